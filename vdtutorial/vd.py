"""Sparse variational dropout (Molchanov, Ashukha & Vetrov, 2017), the regulariser of the paper's
pre-training phase (Section III-B): the layers, their KL term and pruning.

The model (paper, eq. 4)
    Every weight gets its own Gaussian multiplicative noise, w_ij = theta_ij (1 + sqrt(alpha_ij) eps_ij),
    i.e. w_ij ~ N(theta_ij, alpha_ij theta_ij^2). Large alpha means "this weight is mostly noise": by the
    Gaussian/binary dropout correspondence alpha = p / (1 - p), alpha > e^3 is binary dropout with
    p > 0.95, and the paper drops such weights for the RL phase (Section IV).

Reading and exploiting sparsity
    :mod:`vdtutorial.analysis` counts pruned weights and neurons (``sparsity_report``) and removes pruned
    neurons physically (``compact``); here :func:`pruned_fraction` gives the share of pruned weights.

Taught in chapter 04.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

#: Range that log alpha is clipped to (:class:`SVDOLayer`, "Clipping log alpha").
LOG_ALPHA_MIN, LOG_ALPHA_MAX = -8.0, 8.0
#: Pruning threshold on log alpha: alpha > e^3, i.e. binary dropout with p > 0.95 (paper, Section IV).
THRESHOLD = 3.0
#: Initial log sigma^2 of every weight: almost no noise at the start of training.
LOG_SIGMA2_INIT = -10.0
#: Small constant inside log(theta^2 + EPS) and sqrt(var + EPS): keeps both finite at theta = 0 / x = 0.
EPS = 1e-8
#: Constants of Molchanov et al.'s fit of -KL(q || log-uniform prior) as a function of log alpha.
K1, K2, K3 = 0.63576, 1.87320, 1.48695


def kl_approx(log_alpha: torch.Tensor) -> torch.Tensor:
    """Elementwise KL(q(w | theta, alpha) || log-uniform prior), Molchanov et al.'s approximation.

    -KL ~ k1 sigmoid(k2 + k3 log alpha) - 0.5 log(1 + 1/alpha) - k1, with log(1 + exp(-log alpha)) computed as
    ``softplus(-log_alpha)`` so it neither overflows nor loses precision. The KL is positive, decreases monotonically in
    alpha and tends to 0 as alpha -> infinity: that slope pushes unneeded weights to pure noise, i.e. to pruning.

    Objective (paper, eqs. 1-3)
        Maximise the variational lower bound N/M sum_m log p(y_m | x_m, w) - KL(q || p) with a log-uniform prior p,
        whose KL term depends on alpha only and has no closed form (hence the fit above). Per example, the loss to
        minimise is the mean negative log-likelihood plus beta * KL / N; a warm-up of beta from 0 to 1 lets the data
        term shape theta before the prior starts pruning.
    """
    neg_kl = K1 * torch.sigmoid(K2 + K3 * log_alpha) - 0.5 * F.softplus(-log_alpha) - K1
    return -neg_kl


class SVDOLayer(nn.Module):
    """What the sparse-VD linear and convolutional layers share: parameters, the train / eval / pruned forward, the
    KL term and pruning. Subclasses only say how a weight tensor is applied (``_op``).

    Additive parametrisation
        Learning alpha directly makes the gradient with respect to theta very noisy once alpha is large. As Molchanov
        et al. do, each layer learns ``log_sigma2`` (the log variance sigma^2 = alpha theta^2 of the weight) next to
        ``theta`` (the attribute ``weight``), and derives ``log_alpha = log_sigma2 - log(theta^2 + 1e-8)``.
        ``log_sigma2`` starts at -10: the noise is negligible at first and the network starts as an ordinary one.
        (A consequence: weights initialised with |theta| < e^((-10 - 3) / 2) ~ 0.0015 are pruned from the start.)

    Clipping log alpha to [-8, 8]
        Below -8 the noise standard deviation is under e^-4 ~ 2% of |theta| and the KL term is nearly flat, so
        nothing is lost; above 8 the weight is dropped with p > 0.9997 anyway. Clipping keeps ``log(theta^2)`` from
        running to -infinity as theta shrinks to zero, which would otherwise make the KL value and its gradient explode.

    Local reparameterisation (the efficient form of eq. 4)
        The weights of one layer are independent Gaussians, so each pre-activation is Gaussian with mean
        x theta^T + b and variance x^2 sigma^2^T. Sampling the pre-activations instead of the weights costs one extra
        matrix product and one noise draw per output instead of per weight, and gives a lower-variance gradient
        estimate (the noise is independent between the examples of a mini-batch).
    """

    def __init__(self, weight_shape: tuple[int, ...], bias: bool):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(weight_shape))
        self.bias = nn.Parameter(torch.empty(weight_shape[0])) if bias else None
        self.log_sigma2 = nn.Parameter(torch.full(weight_shape, LOG_SIGMA2_INIT))
        # The frozen mask and the flag are buffers so that a pruned layer survives a state_dict round trip.
        self.register_buffer("mask", torch.ones(weight_shape, dtype=torch.bool))
        self.register_buffer("pruned", torch.tensor(False))
        self.register_load_state_dict_post_hook(_refreeze_after_load)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Same initial theta and bias distribution as torch's plain layers, U(-1/sqrt(fan_in), ..), so that
        switching a network between plain and variational layers changes only the regulariser."""
        bound = 1.0 / math.sqrt(self.weight[0].numel())
        nn.init.uniform_(self.weight, -bound, bound)
        if self.bias is not None:
            nn.init.uniform_(self.bias, -bound, bound)

    @property
    def log_alpha(self) -> torch.Tensor:
        """log alpha = log sigma^2 - log theta^2, clipped to [LOG_ALPHA_MIN, LOG_ALPHA_MAX]."""
        return torch.clamp(self.log_sigma2 - torch.log(self.weight**2 + EPS), LOG_ALPHA_MIN, LOG_ALPHA_MAX)

    def keep_mask(self, threshold: float = THRESHOLD) -> torch.Tensor:
        """Boolean mask of the kept weights: log alpha <= threshold, or the frozen mask once the layer is pruned."""
        return self.mask if self.pruned else self.log_alpha <= threshold

    def kl(self) -> torch.Tensor:
        """KL(q || prior) summed over the layer's weights (biases carry no noise and no prior)."""
        return kl_approx(self.log_alpha).sum()

    @torch.no_grad()
    def prune_(self, threshold: float = THRESHOLD) -> "SVDOLayer":
        """Freeze the mask log alpha <= threshold for RL fine-tuning (idempotent): from then on the forward pass is
        always eval mode's deterministic ``theta * mask`` (also in train mode), ``log_sigma2`` stops training (the paper
        trains W but not alpha in the RL phase), and pruned thetas are set to zero and get an exactly zero gradient, so
        no gradient-based optimiser (Adam, or TRPO's conjugate-gradient step) can revive them."""
        self.mask.copy_(self.keep_mask(threshold))
        self.weight.mul_(self.mask)
        self.pruned.fill_(True)
        self.log_sigma2.requires_grad_(False)
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.pruned or not self.training:
            return self._op(x, self.weight * self.keep_mask(), self.bias)
        mean = self._op(x, self.weight, self.bias)
        var = self._op(x * x, torch.exp(self.log_sigma2), None)
        return mean + torch.sqrt(var + EPS) * torch.randn_like(mean)

    def _op(self, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
        raise NotImplementedError


def _refreeze_after_load(layer: SVDOLayer, _incompatible_keys) -> None:
    """``requires_grad`` is not part of a state_dict: re-derive it from the loaded ``pruned`` flag."""
    layer.log_sigma2.requires_grad_(not bool(layer.pruned))


class LinearSVDO(SVDOLayer):
    """Fully connected layer with sparse variational dropout; drop-in replacement for ``nn.Linear``."""

    def __init__(self, in_features: int, out_features: int, bias: bool = True):
        super().__init__((out_features, in_features), bias)
        self.in_features, self.out_features = in_features, out_features

    def _op(self, x, weight, bias):
        return F.linear(x, weight, bias)

    def extra_repr(self) -> str:
        return f"in_features={self.in_features}, out_features={self.out_features}, bias={self.bias is not None}"


def _pair(value) -> tuple[int, int]:
    return (value, value) if isinstance(value, int) else tuple(value)


class Conv2dSVDO(SVDOLayer):
    """2-D convolution with sparse variational dropout; drop-in replacement for ``nn.Conv2d`` (no groups, no
    dilation). Under local reparameterisation the output variance is the convolution of x^2 with sigma^2, exactly as
    for the linear layer, since a convolution is a linear map with shared weights."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size, stride=1, padding=0, bias: bool = True):
        kernel_size = _pair(kernel_size)
        super().__init__((out_channels, in_channels, *kernel_size), bias)
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size, self.stride, self.padding = kernel_size, _pair(stride), _pair(padding)

    def _op(self, x, weight, bias):
        return F.conv2d(x, weight, bias, self.stride, self.padding)

    def extra_repr(self) -> str:
        return (
            f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, stride={self.stride}, "
            f"padding={self.padding}, bias={self.bias is not None}"
        )


def make_linear(in_features: int, out_features: int, variational: bool, bias: bool = True) -> nn.Module:
    """``LinearSVDO`` when ``variational`` else ``nn.Linear``: one switch builds either network."""
    return (LinearSVDO if variational else nn.Linear)(in_features, out_features, bias=bias)


def make_conv2d(
    in_channels: int, out_channels: int, kernel_size, stride=1, padding=0, variational: bool = False, bias: bool = True
) -> nn.Module:
    """``Conv2dSVDO`` when ``variational`` else ``nn.Conv2d``."""
    return (Conv2dSVDO if variational else nn.Conv2d)(
        in_channels, out_channels, kernel_size, stride=stride, padding=padding, bias=bias
    )


def svdo_layers(module: nn.Module) -> list[SVDOLayer]:
    """All sparse-VD layers inside ``module`` (in ``module.modules()`` order)."""
    return [m for m in module.modules() if isinstance(m, SVDOLayer)]


def model_kl(module: nn.Module) -> torch.Tensor:
    """Total KL of ``module``'s sparse-VD layers; zero for a plain network, so one training loop serves both models."""
    return sum((layer.kl() for layer in svdo_layers(module)), torch.zeros(()))


def prune_model(module: nn.Module, threshold: float = THRESHOLD) -> nn.Module:
    """Call :meth:`prune_` on every sparse-VD layer of ``module`` (start of the paper's RL phase)."""
    for layer in svdo_layers(module):
        layer.prune_(threshold)
    return module


#: The layers that hold weights (plain or sparse VD): the units of the network's wiring, and what the Fisher
#: products of :mod:`vdtutorial.fast.fisher` differentiate.
WEIGHT_LAYERS = (nn.Linear, nn.Conv2d, SVDOLayer)


@torch.no_grad()
def pruned_fraction(module: nn.Module, threshold: float = THRESHOLD) -> float:
    """Fraction of the weights (biases excluded) of ``module``'s sparse-VD layers with log alpha > ``threshold``, the
    number pre-training logs each epoch; :func:`vdtutorial.analysis.sparsity.sparsity_report` gives it per layer."""
    layers = svdo_layers(module)
    return sum(int((~layer.keep_mask(threshold)).sum()) for layer in layers) / sum(
        layer.weight.numel() for layer in layers
    )
