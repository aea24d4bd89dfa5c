"""Sparse variational dropout (Molchanov, Ashukha & Vetrov, 2017), the regulariser of the paper's
pre-training phase (Section III-B), plus the tools to read and exploit the sparsity it produces.

The model (paper, eq. 4)
    Every weight gets its own Gaussian multiplicative noise, w_ij = theta_ij (1 + sqrt(alpha_ij) eps_ij),
    i.e. w_ij ~ N(theta_ij, alpha_ij theta_ij^2). Large alpha means "this weight is mostly noise": by the
    Gaussian/binary dropout correspondence alpha = p / (1 - p), alpha > e^3 is binary dropout with
    p > 0.95, and the paper drops such weights for the RL phase (Section IV).

Reading and exploiting sparsity
    :func:`sparsity_report` counts pruned weights and pruned neurons; :func:`compact` removes pruned
    neurons physically, giving a smaller plain network with identical eval-mode outputs. Both need the
    network's wiring, described as :class:`Edge` lists (:func:`chain` derives them for ``nn.Sequential``
    stacks; composite modules provide a ``weight_edges()`` method).

Taught in chapter 04.
"""
from __future__ import annotations

import copy
import math
from collections import defaultdict
from dataclasses import dataclass

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

    -KL ~ k1 sigmoid(k2 + k3 log alpha) - 0.5 log(1 + 1/alpha) - k1, with log(1 + exp(-log alpha))
    computed as ``softplus(-log_alpha)`` so it neither overflows nor loses precision. The KL is
    positive, decreases monotonically in alpha and tends to 0 as alpha -> infinity: that slope is what
    pushes unnecessary weights towards pure noise, i.e. towards being pruned.

    Objective (paper, eqs. 1-3)
        Maximise the variational lower bound N/M sum_m log p(y_m | x_m, w) - KL(q || p) with a log-uniform
        prior p. Its KL term depends on alpha only and has no closed form; :func:`kl_approx` uses Molchanov's
        fitted approximation. Per example, the loss to minimise is the mean negative log-likelihood plus
        beta * KL / N; a warm-up of beta from 0 to 1 lets the data term shape theta before the prior starts
        pruning.
    """
    neg_kl = K1 * torch.sigmoid(K2 + K3 * log_alpha) - 0.5 * F.softplus(-log_alpha) - K1
    return -neg_kl


class SVDOLayer(nn.Module):
    """What the sparse-VD linear and convolutional layers share: parameters, the train / eval / pruned
    forward, the KL term and pruning. Subclasses only say how a weight tensor is applied (``_op``).

    Additive parametrisation
        Learning alpha directly makes the gradient with respect to theta very noisy once alpha is large. As
        Molchanov et al. do, each layer learns ``log_sigma2`` (the log variance sigma^2 = alpha theta^2 of
        the weight) next to ``theta`` (the attribute ``weight``), and derives
        ``log_alpha = log_sigma2 - log(theta^2 + 1e-8)``. ``log_sigma2`` starts at -10: the noise is
        negligible at first and the network starts as an ordinary one. (A consequence: weights initialised
        with |theta| < e^((-10 - 3) / 2) ~ 0.0015 are pruned from the start.)

    Clipping log alpha to [-8, 8]
        Below -8 the noise standard deviation is under e^-4 ~ 2% of |theta| and the KL term is nearly flat,
        so nothing is lost; above 8 the weight is dropped with p > 0.9997 anyway. Clipping keeps
        ``log(theta^2)`` from running to -infinity as theta shrinks to zero, which would otherwise make the
        KL value and its gradient explode.

    Local reparameterisation (the efficient form of eq. 4)
        The weights of one layer are independent Gaussians, so each pre-activation is Gaussian with mean
        x theta^T + b and variance x^2 sigma^2^T. Sampling the pre-activations instead of the weights costs
        one extra matrix product and one noise draw per output instead of per weight, and gives a
        lower-variance gradient estimate (the noise is independent between the examples of a mini-batch).
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
        """Boolean mask of the weights that are kept: log alpha <= threshold, or the frozen mask once the
        layer has been pruned (then ``threshold`` is ignored: the mask no longer changes)."""
        return self.mask if self.pruned else self.log_alpha <= threshold

    def kl(self) -> torch.Tensor:
        """KL(q || prior) summed over the layer's weights (biases carry no noise and no prior)."""
        return kl_approx(self.log_alpha).sum()

    @torch.no_grad()
    def prune_(self, threshold: float = THRESHOLD) -> "SVDOLayer":
        """Freeze the mask log alpha <= threshold for RL fine-tuning (idempotent).

        Pruning and fine-tuning
            In eval mode a layer is deterministic and uses theta with the weights of log alpha > 3 set to zero.
            :meth:`prune_` freezes that mask for the RL phase: from then on the forward pass is always the
            deterministic ``theta * mask`` (also in train mode), ``log_sigma2`` stops training (the paper trains W
            but not alpha in the RL phase), pruned thetas are set to zero and get an exactly zero gradient, so
            no gradient-based optimiser (Adam, or TRPO's conjugate-gradient step) can revive them.
        """
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
    """2-D convolution with sparse variational dropout; drop-in replacement for ``nn.Conv2d`` (no groups,
    no dilation). Under local reparameterisation the output variance is the convolution of x^2 with
    sigma^2, exactly as for the linear layer, since a convolution is a linear map with shared weights."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size, stride=1, padding=0, bias: bool = True):
        kernel_size = _pair(kernel_size)
        super().__init__((out_channels, in_channels, *kernel_size), bias)
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size, self.stride, self.padding = kernel_size, _pair(stride), _pair(padding)

    def _op(self, x, weight, bias):
        return F.conv2d(x, weight, bias, self.stride, self.padding)

    def extra_repr(self) -> str:
        return (f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, stride={self.stride}, "
                f"padding={self.padding}, bias={self.bias is not None}")


def make_linear(in_features: int, out_features: int, variational: bool, bias: bool = True) -> nn.Module:
    """``LinearSVDO`` when ``variational`` else ``nn.Linear``: one switch builds either network."""
    return (LinearSVDO if variational else nn.Linear)(in_features, out_features, bias=bias)


def make_conv2d(in_channels: int, out_channels: int, kernel_size, stride=1, padding=0, variational: bool = False,
                bias: bool = True) -> nn.Module:
    """``Conv2dSVDO`` when ``variational`` else ``nn.Conv2d``."""
    return (Conv2dSVDO if variational else nn.Conv2d)(in_channels, out_channels, kernel_size, stride=stride,
                                                     padding=padding, bias=bias)


def svdo_layers(module: nn.Module) -> list[SVDOLayer]:
    """All sparse-VD layers inside ``module`` (in ``module.modules()`` order)."""
    return [m for m in module.modules() if isinstance(m, SVDOLayer)]


def model_kl(module: nn.Module) -> torch.Tensor:
    """Sum of the KL terms of every sparse-VD layer of ``module``; zero for a plain network, so a single
    training loop serves both the plain and the variational model."""
    return sum((layer.kl() for layer in svdo_layers(module)), torch.zeros(()))


def prune_model(module: nn.Module, threshold: float = THRESHOLD) -> nn.Module:
    """Call :meth:`prune_` on every sparse-VD layer of ``module`` (start of the paper's RL phase)."""
    for layer in svdo_layers(module):
        layer.prune_(threshold)
    return module


# --------------------------------------------------------------------------------------------------
# Network wiring: which layer's output units feed which layer's input columns.
# --------------------------------------------------------------------------------------------------
#: The layers that hold weights (plain or sparse VD): the units of the network's wiring, and what the Fisher
#: products of :mod:`vdtutorial.fast.fisher` differentiate.
WEIGHT_LAYERS = (nn.Linear, nn.Conv2d, SVDOLayer)
#: Modules allowed between two weight layers: they act on each unit separately, so a unit whose value
#: is a constant c stays a constant (act(c)) and a unit nobody reads stays unread.
ELEMENTWISE = (nn.ReLU, nn.Tanh, nn.ELU, nn.LeakyReLU, nn.Sigmoid, nn.Softplus, nn.GELU, nn.SiLU, nn.Identity)


@dataclass(frozen=True, eq=False)
class Edge:
    """Output units of ``src`` feed input columns ``offset + j * repeat ... offset + (j + 1) * repeat - 1``
    of ``dst`` (unit j; ``repeat`` = H * W when a ``Flatten`` turns each channel into H * W columns),
    after the elementwise modules ``post`` (the activations between the two layers)."""

    src: nn.Module
    dst: nn.Module
    offset: int = 0
    repeat: int = 1
    post: tuple[nn.Module, ...] = ()


def weight_layers(module: nn.Module) -> list[nn.Module]:
    """All plain and sparse-VD Linear / Conv2d layers of ``module``."""
    return [m for m in module.modules() if isinstance(m, WEIGHT_LAYERS)]


def _units(layer: nn.Module) -> int:
    return layer.weight.shape[0]


def _columns(layer: nn.Module) -> int:
    return layer.weight.shape[1]


def chain(seq: nn.Sequential) -> tuple[list[Edge], tuple[nn.Module, tuple[nn.Module, ...]]]:
    """Edges of a ``nn.Sequential`` of Linear / Conv2d (plain or sparse VD), elementwise activations and
    ``Flatten``; also returns its open end ``(last weight layer, activations after it)``, which
    :func:`concat_edges` connects to a layer that reads several streams."""
    edges, last, post, flattened = [], None, [], False
    for m in seq:
        if isinstance(m, WEIGHT_LAYERS):
            if last is not None:
                edges.append(_sequential_edge(last, m, flattened, tuple(post)))
            last, post, flattened = m, [], False
        elif isinstance(m, nn.Flatten):
            flattened = True
        elif isinstance(m, ELEMENTWISE):
            post.append(m)
        else:
            raise TypeError(f"chain() handles Linear/Conv2d layers, elementwise activations and Flatten, not {m!r}")
    if last is None:
        raise ValueError("the Sequential has no Linear or Conv2d layer")
    return edges, (last, tuple(post))


def _sequential_edge(src: nn.Module, dst: nn.Module, flattened: bool, post: tuple[nn.Module, ...]) -> Edge:
    conv_src, conv_dst = src.weight.dim() == 4, dst.weight.dim() == 4
    if conv_dst and not conv_src:
        raise TypeError(f"a convolution cannot follow a fully connected layer: {src!r} -> {dst!r}")
    if conv_src and not conv_dst:
        if not flattened or _columns(dst) % _units(src):
            raise TypeError(f"{src!r} -> {dst!r} needs a Flatten and in_features divisible by the channels")
        return Edge(src, dst, repeat=_columns(dst) // _units(src), post=post)
    if _columns(dst) != _units(src):
        raise ValueError(f"size mismatch between {src!r} and {dst!r}")
    return Edge(src, dst, post=post)


def concat_edges(tails: list[tuple[nn.Module, tuple[nn.Module, ...]]], dst: nn.Module) -> list[Edge]:
    """Edges from the open ends of several streams (see :func:`chain`) into ``dst``, which reads their
    outputs concatenated in that order."""
    edges, offset = [], 0
    for src, post in tails:
        edges.append(Edge(src, dst, offset=offset, post=post))
        offset += _units(src)
    if offset != _columns(dst):
        raise ValueError(f"the streams give {offset} features but {dst!r} reads {_columns(dst)}")
    return edges


def graph(module: nn.Module) -> list[Edge]:
    """The edges of ``module``: from its ``weight_edges()`` method if it has one, else of a Sequential."""
    if hasattr(module, "weight_edges"):
        return module.weight_edges()
    if isinstance(module, nn.Sequential):
        return chain(module)[0]
    raise TypeError(f"cannot tell how the layers of {type(module).__name__} are wired: use an nn.Sequential "
                    "or give the module a weight_edges() method returning vd.Edge objects")


def _keep_mask(layer: nn.Module, threshold: float = THRESHOLD) -> torch.Tensor:
    """Kept weights of any weight layer: every weight of a plain layer is kept."""
    if isinstance(layer, SVDOLayer):
        return layer.keep_mask(threshold)
    return torch.ones_like(layer.weight, dtype=torch.bool)


def _dead_units(layers, edges, masks) -> dict[nn.Module, tuple[torch.Tensor, torch.Tensor]]:
    """Per layer, boolean vectors over its output units: (all incoming weights pruned, all outgoing
    weights pruned). Only layers whose units feed another layer (hidden layers) are listed."""
    live_columns = {l: masks[l].transpose(0, 1).reshape(_columns(l), -1).any(1) for l in layers}
    dead_out = {}
    for e in edges:
        n = _units(e.src)
        read = live_columns[e.dst][e.offset:e.offset + n * e.repeat].view(n, e.repeat).any(1)
        dead_out[e.src] = dead_out.get(e.src, torch.ones(n, dtype=torch.bool, device=read.device)) & ~read
    return {l: (~masks[l].reshape(_units(l), -1).any(1), d) for l, d in dead_out.items()}


# --------------------------------------------------------------------------------------------------
# Sparsity report
# --------------------------------------------------------------------------------------------------
@dataclass
class LayerSparsity:
    """One weight layer. Neuron counts refer to the layer's output units (channels for a convolution) and
    are zero for output layers: the network's outputs are never pruned."""

    name: str
    weights: int
    pruned_weights: int
    hidden_units: int
    dead_in: int
    dead_out: int
    dead: int


@dataclass
class SparsityReport:
    """Weight and neuron sparsity of a network at a log-alpha threshold.

    Neuron definitions: a hidden unit is *dead-in* when all its incoming weights are pruned (its output
    is the constant act(bias)), *dead-out* when all its outgoing weights are pruned (nobody reads it),
    and *pruned* when either holds, since either way it can be removed from the computation
    (:func:`compact` folds the constant of a dead-in unit into the next layer's bias).
    ``neuron_fraction`` (either definition) is the number to compare with the paper's Table I "neuron
    sparsification ratio"; the paper's sentence "the number of weights is reduced to less than a quarter"
    next to a ratio of 0.766 fits a count of whole removed units better than a count of weights.
    """

    layers: list[LayerSparsity]
    threshold: float

    def _total(self, field: str) -> int:
        return sum(getattr(l, field) for l in self.layers)

    @property
    def weight_fraction(self) -> float:
        """Fraction of all weights (biases excluded) that are pruned."""
        return self._total("pruned_weights") / self._total("weights")

    @property
    def compression(self) -> float:
        """Total weights / kept weights."""
        kept = self._total("weights") - self._total("pruned_weights")
        return self._total("weights") / kept if kept else math.inf

    def _neuron_fraction(self, field: str) -> float:
        hidden = self._total("hidden_units")
        return self._total(field) / hidden if hidden else 0.0

    @property
    def neuron_fraction(self) -> float:
        """Fraction of hidden units that are dead-in or dead-out (the Table I quantity)."""
        return self._neuron_fraction("dead")

    @property
    def neuron_fraction_in(self) -> float:
        """Fraction of hidden units with all incoming weights pruned."""
        return self._neuron_fraction("dead_in")

    @property
    def neuron_fraction_out(self) -> float:
        """Fraction of hidden units with all outgoing weights pruned."""
        return self._neuron_fraction("dead_out")

    def __str__(self) -> str:
        rows = [f"{'layer':<24}{'weights':>10}{'% pruned':>9}{'units':>7}{'dead-in':>9}{'dead-out':>10}"
                f"{'units pruned':>14}"]
        for l in self.layers:
            rows.append(f"{l.name:<24}{l.weights:>10}{l.pruned_weights / l.weights:>9.1%}{l.hidden_units:>7}"
                        f"{l.dead_in:>9}{l.dead_out:>10}{l.dead:>14}")
        rows.append(f"weights pruned {self.weight_fraction:.1%} (compression x{self.compression:.1f}); neurons pruned "
                    f"{self.neuron_fraction:.1%} (dead-in {self.neuron_fraction_in:.1%}, dead-out "
                    f"{self.neuron_fraction_out:.1%}); threshold log alpha > {self.threshold:g}")
        return "\n".join(rows)


@torch.no_grad()
def sparsity_report(module: nn.Module, threshold: float = THRESHOLD) -> SparsityReport:
    """Pruned weights and neurons of ``module`` if weights with log alpha > ``threshold`` were dropped
    (already pruned layers report their frozen mask). Plain layers count as fully kept."""
    names = {m: name or type(m).__name__ for name, m in module.named_modules()}
    layers = weight_layers(module)
    masks = {l: _keep_mask(l, threshold) for l in layers}
    dead = _dead_units(layers, graph(module), masks)
    rows = []
    for l in layers:
        row = dict(name=names[l], weights=masks[l].numel(), pruned_weights=int((~masks[l]).sum()),
                   hidden_units=0, dead_in=0, dead_out=0, dead=0)
        if l in dead:
            dead_in, dead_out = dead[l]
            row.update(hidden_units=_units(l), dead_in=int(dead_in.sum()), dead_out=int(dead_out.sum()),
                       dead=int((dead_in | dead_out).sum()))
        rows.append(LayerSparsity(**row))
    return SparsityReport(rows, threshold)


# --------------------------------------------------------------------------------------------------
# Compaction
# --------------------------------------------------------------------------------------------------
def _fold_is_exact(layer: nn.Module) -> bool:
    """A constant input channel adds a constant to every output of ``layer`` only without zero padding
    (with padding, border outputs see fewer copies of the constant)."""
    return layer.weight.dim() == 2 or all(p == 0 for p in layer.padding)


def _plain_like(layer: nn.Module, weight: torch.Tensor, bias: torch.Tensor | None) -> nn.Module:
    if weight.dim() == 2:
        new = nn.Linear(weight.shape[1], weight.shape[0], bias=bias is not None)
    else:
        if getattr(layer, "groups", 1) != 1 or tuple(getattr(layer, "dilation", (1, 1))) != (1, 1):
            raise TypeError(f"compact() does not handle grouped or dilated convolutions: {layer!r}")
        new = nn.Conv2d(weight.shape[1], weight.shape[0], layer.kernel_size, stride=layer.stride,
                        padding=layer.padding, bias=bias is not None)
    new.weight.copy_(weight)
    if bias is not None:
        new.bias.copy_(bias)
    return new


@torch.no_grad()
def compact_layers(module: nn.Module, edges: list[Edge]) -> dict[nn.Module, nn.Module]:
    """Plain replacements, with pruned units removed, for every weight layer of ``module`` wired by
    ``edges``; building block of :func:`compact` and of composite modules' ``compact()`` methods.

    A hidden unit is removed when it is dead-out (its outgoing weights are all zero, so its value is
    irrelevant) or dead-in (its value is the constant c = post(bias)) provided every consumer can absorb
    the constant into its bias exactly. The consumer's bias then gains W[:, cols] c; for a dead-out unit
    that product is zero. Pruned weights among the kept units stay as explicit zeros.
    """
    layers = weight_layers(module)
    masks = {l: _keep_mask(l) for l in layers}
    weights = {l: l.weight * masks[l] for l in layers}
    dead = _dead_units(layers, edges, masks)
    consumers, producers = defaultdict(list), defaultdict(list)
    for e in edges:
        consumers[e.src].append(e)
        producers[e.dst].append(e)
    keep = {}
    for l in layers:
        keep[l] = torch.ones(_units(l), dtype=torch.bool)
        if l in dead:
            dead_in, dead_out = dead[l]
            foldable = all(_fold_is_exact(e.dst) for e in consumers[l])
            keep[l] = ~(dead_out | (dead_in & foldable))
    new = {}
    for l in layers:
        columns = torch.ones(_columns(l), dtype=torch.bool)
        constants = torch.zeros(_columns(l))
        for e in producers[l]:
            n = _units(e.src)
            bias = e.src.bias if e.src.bias is not None else torch.zeros(n)
            value = nn.Sequential(*e.post)(bias.view(1, n)).view(n)
            span = slice(e.offset, e.offset + n * e.repeat)
            columns[span] = keep[e.src].repeat_interleave(e.repeat)
            constants[span] = torch.where(keep[e.src], 0.0, value).repeat_interleave(e.repeat)
        w = weights[l]
        fold = w.reshape(*w.shape[:2], -1).sum(-1) @ constants
        bias = None
        if l.bias is not None or bool(fold.any()):
            bias = (l.bias if l.bias is not None else 0.0) + fold
            bias = bias[keep[l]]
        new[l] = _plain_like(l, w[keep[l]][:, columns], bias)
    return new


def rebuild_sequential(seq: nn.Sequential, replacements: dict[nn.Module, nn.Module]) -> nn.Sequential:
    """Copy of ``seq`` with its weight layers swapped for their ``replacements``."""
    return nn.Sequential(*(replacements[m] if m in replacements else copy.deepcopy(m) for m in seq))


def compact(module: nn.Module) -> nn.Module:
    """Plain network with pruned neurons physically removed; same outputs as ``module`` in eval mode.

    Works for ``nn.Sequential`` stacks of Linear / Conv2d (plain or sparse VD), elementwise activations and
    ``Flatten`` (a removed channel removes its H * W columns of the following Linear layer), and for
    modules with their own ``compact()`` method (e.g. :class:`vdtutorial.policy.TwoStreamNet`). The input
    and output sizes are unchanged; hidden layers shrink.
    """
    if isinstance(module, nn.Sequential):
        return rebuild_sequential(module, compact_layers(module, chain(module)[0]))
    if hasattr(module, "compact"):
        return module.compact()
    raise TypeError(f"compact() handles nn.Sequential or modules with a compact() method, not {type(module).__name__}")
