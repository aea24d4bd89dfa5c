r"""The exact Fisher-vector product of the Gaussian policy, computed in Gauss-Newton form.

TRPO's conjugate gradient needs F v about a dozen times per update, where F is the Hessian of the mean
KL(pi_old || pi_theta) at theta = theta_old (:mod:`vdtutorial.trpo`, step 4). The generic way
(:func:`vdtutorial.trpo.fisher_vector_product`, the one chapter 06 teaches) differentiates the KL
twice with autograd. For the paper's policy pi(a | s) = N(mu(s), diag(sigma(s)^2)) the same matrix has
a closed form (chapter 06 derives it): with J the Jacobian of the network outputs (mu, sigma) with
respect to theta, on N states,

    F = J^T M J,   M = diag(1 / sigma^2) on the mu outputs, diag(2 / sigma^2) on the sigma outputs, / N.

So F v = J^T (M (J v)): one Jacobian-vector product, pushing the parameter direction v forwards
through the two networks, and one vector-Jacobian product, an ordinary backward pass. Both reuse one
forward pass at theta_old per update: its activations are cached for the forward product and its
autograd graph is kept for the backward one. This is exact, not an approximation: the terms of the
KL's Hessian that involve second derivatives of the networks are multiplied by the KL's first
derivatives with respect to (mu, sigma), which are zero at theta_old.

Why the forward product is written out here instead of using autograd: the double backward (and the
"double-vjp" trick that gets J v from two backward passes) go through the convolutions' double-backward
kernels, which also compute terms nobody needs (for the first convolution, a transposed convolution
back onto the image) and are several times slower than a plain convolution; forward-mode AD
(``torch.func.jvp``) recomputes the whole forward pass, input normalisation included, for every v;
``torch.func.linearize`` avoids that but spends seconds tracing the networks at every update. A tangent
pass over the cached activations costs about one forward pass per layer, and the masks of pruned
weights (chapter 04) enter it the same way as the forward pass: the product along a pruned weight, and
along a parameter that is frozen or that the outputs do not depend on, is exactly 0.

Supported: :class:`vdtutorial.policy.GaussianPolicy` whose networks are built from plain or sparse-VD
Linear / Conv2d layers, ReLU, Tanh and Flatten (every network :func:`vdtutorial.policy.make_policy`
builds), with sparse-VD layers pruned or in eval mode (in train mode an unpruned sparse-VD layer is
random, and TRPO's policy must be deterministic). :func:`supports` says whether a policy qualifies;
TRPO falls back to the double backward for any other policy.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal

from vdtutorial.policy import GaussianPolicy, TwoStreamNet
from vdtutorial.vd import SVDOLayer

#: Layers whose parameters the products cover, and the parameter-free modules they may be mixed with.
WEIGHT_LAYERS = (nn.Linear, nn.Conv2d, SVDOLayer)
ACTIVATIONS = (nn.ReLU, nn.Tanh, nn.Flatten)


def supports(policy: nn.Module) -> bool:
    """True when :class:`GaussNewtonFisher` computes the Fisher-vector products of ``policy``."""
    if type(policy) is not GaussianPolicy:  # a subclass may change distribution()
        return False
    for net in (policy.mu, policy.sigma):
        for module in [m for stream in net.streams for m in stream] + list(net.head):
            if not isinstance(module, WEIGHT_LAYERS + ACTIVATIONS):
                return False
            if isinstance(module, SVDOLayer) and module.training and not module.pruned:
                return False
            if isinstance(module, nn.Conv2d) and module.padding_mode != "zeros":
                return False
    return True


def _weight_and_mask(layer: nn.Module) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The weight the forward pass uses and the 0/1 mask it was multiplied by (None: no mask)."""
    if isinstance(layer, SVDOLayer):
        mask = layer.keep_mask().to(layer.weight.dtype)
        return layer.weight * mask, mask
    return layer.weight, None


def _apply(layer: nn.Module, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``layer``'s affine map with the given weight and bias (a tangent pass uses it with tangents)."""
    if isinstance(layer, SVDOLayer):
        return layer._op(x, weight, bias)
    if isinstance(layer, nn.Conv2d):
        return layer._conv_forward(x, weight, bias)
    return F.linear(x, weight, bias)


class _Trace:
    """One forward pass through a ``nn.Sequential``, keeping every module's input and output."""

    def __init__(self, seq: nn.Sequential, x: torch.Tensor):
        self.steps = []
        for module in seq:
            if isinstance(module, WEIGHT_LAYERS):
                weight, mask = _weight_and_mask(module)
                y = _apply(module, x, weight, module.bias)
                self.steps.append((module, x.detach(), y.detach(), weight.detach(), mask))
            else:
                y = module(x)
                self.steps.append((module, None, y.detach(), None, None))
            x = y
        self.output = x

    def tangent(self, tangents: dict[nn.Parameter, torch.Tensor], t: torch.Tensor | None) -> torch.Tensor:
        """d output along the parameter direction ``tangents``, given ``t`` = d input (None: the input
        is data and does not move). A parameter missing from ``tangents`` does not move."""
        for module, x, y, weight, mask in self.steps:
            if isinstance(module, WEIGHT_LAYERS):
                dw, db = tangents.get(module.weight), tangents.get(module.bias)
                if dw is None:
                    dw = torch.zeros_like(weight)
                elif mask is not None:
                    dw = dw * mask
                dy = _apply(module, x, dw, db)
                t = dy if t is None else dy + _apply(module, t, weight, None)
            elif isinstance(module, nn.ReLU):
                t = t * (y > 0)
            elif isinstance(module, nn.Tanh):
                t = t * (1 - y * y)
            else:  # Flatten
                t = module(t)
        return t


class _NetTrace:
    """A :class:`TwoStreamNet`'s forward pass at the current parameters, traced for tangent passes."""

    def __init__(self, net: TwoStreamNet, obs):
        self.streams = [_Trace(stream, x) for stream, x in zip(net.streams, net._stream_inputs(obs))]
        self.head = _Trace(net.head, torch.cat([s.output for s in self.streams], dim=-1))
        self.output = self.head.output

    def tangent(self, tangents: dict[nn.Parameter, torch.Tensor]) -> torch.Tensor:
        features = torch.cat([s.tangent(tangents, None) for s in self.streams], dim=-1)
        return self.head.tangent(tangents, features)


class GaussNewtonFisher:
    """v -> F v for a :class:`GaussianPolicy` on a batch of observations, F the Hessian of the mean
    KL(old || pi_theta) at the current parameters theta = theta_old (see the module docstring).

    policy: a policy for which :func:`supports` holds. obs: the batch (the states the mean KL averages
    over). old: the policy's own distribution on ``obs`` at the current parameters, as TRPO's pi_old;
    its sigma gives M. params: the parameters v lives on, in the order of the flat vector (those that
    require grad; any other parameter is held fixed).

    The constructor runs one forward pass (kept for the backward products); each call then costs one
    tangent pass and one backward pass through both networks.
    """

    def __init__(self, policy: GaussianPolicy, obs, old: Normal, params: list[nn.Parameter]):
        if not supports(policy):
            raise TypeError("GaussNewtonFisher needs a GaussianPolicy of Linear/Conv2d/ReLU/Tanh/Flatten layers "
                            "with its sparse-VD layers pruned or in eval mode; use trpo.fisher_vector_product")
        self.params = params
        self.shapes = [p.shape for p in params]
        self.mu, self.sigma = _NetTrace(policy.mu, obs), _NetTrace(policy.sigma, obs)
        self.mean = self.mu.output
        self.std = policy.min_std + F.softplus(self.sigma.output)
        if not (torch.allclose(self.mean, old.mean, rtol=1e-4, atol=1e-6)
                and torch.allclose(self.std, old.stddev, rtol=1e-4, atol=1e-6)):
            raise RuntimeError("GaussNewtonFisher's forward pass disagrees with policy.distribution(): "
                               "the two must compute the same mu and sigma")
        # d sigma / d (sigma network output), and M per output (1/N: the KL is a mean over the batch)
        self.dstd = torch.sigmoid(self.sigma.output.detach())
        variance = old.variance.detach()
        self.m_mean, self.m_std = 1 / (variance * len(variance)), 2 / (variance * len(variance))

    def __call__(self, v: torch.Tensor) -> torch.Tensor:
        """F v (no damping) as a flat vector in the order of ``params``."""
        pieces = torch.split(v, [p.numel() for p in self.params])
        tangents = {p: piece.view_as(p) for p, piece in zip(self.params, pieces)}
        jv_mean = self.mu.tangent(tangents)
        jv_std = self.dstd * self.sigma.tangent(tangents)
        grads = torch.autograd.grad((self.mean, self.std), self.params,
                                    (self.m_mean * jv_mean, self.m_std * jv_std),
                                    retain_graph=True, allow_unused=True)
        return torch.cat([(v.new_zeros(s) if g is None else g).reshape(-1) for s, g in zip(self.shapes, grads)])

