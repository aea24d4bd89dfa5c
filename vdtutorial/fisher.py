r"""The exact Fisher-vector product of the Gaussian policy, computed in Gauss-Newton form.

TRPO's conjugate gradient needs F v about a dozen times per update, where F is the Hessian of the mean
KL(pi_old || pi_theta) at theta = theta_old (:mod:`vdtutorial.trpo`, step 4). The generic way
(:func:`vdtutorial.trust_region.fisher_vector_product`, the one chapter 06 teaches) differentiates the KL
twice with autograd. For the paper's policy pi(a | s) = N(mu(s), diag(sigma(s)^2)) the same matrix has
a closed form (chapter 06 derives it): with J the Jacobian of the network outputs (mu, sigma) with
respect to theta, on N states,

    F = J^T M J,   M = diag(1 / sigma^2) on the mu outputs, diag(2 / sigma^2) on the sigma outputs, / N.

The sigma network ends in a softplus, sigma = min_std + softplus(z), and the code takes J with respect to its
pre-activation z: M's sigma entries then carry the chain factor (d sigma / d z)^2 = sigmoid(z)^2.

So F v = J^T (M (J v)): one Jacobian-vector product, pushing the parameter direction v forwards
through the two networks (a tangent pass), and one vector-Jacobian product, an ordinary backward pass.
Both run over the activations of one forward pass at theta_old, cached once per update. This is
exact, not an approximation: the terms of the KL's Hessian that involve second derivatives of the
networks are multiplied by the KL's first derivatives with respect to (mu, sigma), which are zero at
theta_old.

Why both passes are written out here instead of left to autograd. Measured on the rgbd policy (both
networks, 114k parameters, batch 200, one thread, CPU time on the shared machine): the double backward
costs 0.94 s per product; this form 0.17 s, plus 0.52 s once per update (its forward pass and the
unfolded image). The double backward (and the "double-vjp" trick that gets J v from two backward
passes) goes through the convolutions' double-backward kernels, which also compute terms nobody
needs (for the first convolution, a transposed convolution back onto the image); forward-mode AD
(``torch.func.jvp``) recomputes the whole forward pass, input normalisation included, for every v
(1.36 s per product with an autograd backward); ``torch.func.linearize`` avoids that but spends
seconds tracing the networks at every update. And the weight gradient of the first convolution, the
largest layer, is ~4x cheaper as one batched matrix product with the image patches, unfolded once
per update, than with ``convolution_backward``.

Pruning (chapter 04) enters both passes the way it enters the forward pass, as the weight's 0/1 mask:
the product along a pruned weight, and along a parameter that is frozen or that the outputs do not
depend on, is exactly 0.

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
            if isinstance(module, nn.Conv2d) and (module.padding_mode != "zeros" or isinstance(module.padding, str)):
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


def _conv_geometry(layer: nn.Module) -> tuple[tuple, tuple, tuple, int]:
    """stride, padding, dilation, groups of a plain or sparse-VD convolution."""
    if isinstance(layer, nn.Conv2d):
        return layer.stride, layer.padding, layer.dilation, layer.groups
    return layer.stride, layer.padding, (1, 1), 1


def _affine_backward(layer: nn.Module, x: torch.Tensor, x_patches: torch.Tensor | None, weight: torch.Tensor,
                     g: torch.Tensor, input_grad: bool):
    """Gradients of <g, layer(x)> with respect to the weight the layer applies, its bias and (when
    ``input_grad``) its input x. ``x_patches``: x unfolded into the convolution's patches, (N, K, P),
    which turns the weight gradient into one batched matrix product (see the module docstring); only
    given for a layer whose input is data, so then there is no input gradient."""
    if weight.dim() == 2:  # fully connected
        return g.T @ x, g.sum(0), (g @ weight if input_grad else None)
    if x_patches is not None:
        n, c_out = g.shape[:2]
        grad_w = torch.bmm(g.reshape(n, c_out, -1), x_patches.transpose(1, 2)).sum(0).view_as(weight)
        return grad_w, g.sum((0, 2, 3)), None
    stride, padding, dilation, groups = _conv_geometry(layer)
    grad_x, grad_w, grad_b = torch.ops.aten.convolution_backward(
        g, x, weight, [weight.shape[0]], stride, padding, dilation, False, [0, 0], groups, [input_grad, True, True])
    return grad_w, grad_b, grad_x


class _Trace:
    """One forward pass through a ``nn.Sequential`` of weight layers and elementwise activations,
    keeping what the tangent and backward passes need: each weight layer's input and applied weight,
    each activation's derivative at its input, each Flatten's input shape."""

    def __init__(self, seq: nn.Sequential, x: torch.Tensor, input_is_data: bool,
                 patch_cache: dict | None = None):
        """``patch_cache``: unfolded inputs by (input, geometry), shared between traces of networks that
        read the same image (mu and sigma), so that it is unfolded once."""
        self.input_is_data = input_is_data
        self.steps = []
        for module in seq:
            if isinstance(module, WEIGHT_LAYERS):
                weight, mask = _weight_and_mask(module)
                patches = None
                if input_is_data and not self.steps and weight.dim() == 4 and _conv_geometry(module)[3] == 1:
                    stride, padding, dilation, _ = _conv_geometry(module)  # the image network's first layer
                    key = (id(x), weight.shape[2:], stride, padding, dilation)
                    cache = {} if patch_cache is None else patch_cache
                    if key not in cache:
                        cache[key] = F.unfold(x, weight.shape[2:], dilation, padding, stride)
                    patches = cache[key]
                self.steps.append((module, x, weight, mask, patches))
                y = _apply(module, x, weight, module.bias)
            elif isinstance(module, nn.ReLU):
                y = module(x)
                self.steps.append((module, (x > 0).to(x.dtype)))
            elif isinstance(module, nn.Tanh):
                y = module(x)
                self.steps.append((module, 1 - y * y))
            else:  # Flatten
                y = module(x)
                self.steps.append((module, x.shape))
            x = y
        self.output = x

    def tangent(self, tangents: dict[nn.Parameter, torch.Tensor], t: torch.Tensor | None) -> torch.Tensor:
        """d output along the parameter direction ``tangents``, given ``t`` = d input (None: the input
        is data and does not move). A parameter missing from ``tangents`` does not move."""
        for module, *cached in self.steps:
            if isinstance(module, WEIGHT_LAYERS):
                x, weight, mask, _ = cached
                dw, db = tangents.get(module.weight), tangents.get(module.bias)
                if dw is None:
                    dw = torch.zeros_like(weight)
                elif mask is not None:
                    dw = dw * mask
                dy = _apply(module, x, dw, db)
                t = dy if t is None else dy + _apply(module, t, weight, None)
            elif isinstance(module, nn.Flatten):
                t = module(t)
            else:
                t = t * cached[0]
        return t

    def backward(self, g: torch.Tensor, grads: dict[nn.Parameter, torch.Tensor]) -> torch.Tensor | None:
        """Add the gradients of <g, output> with respect to the layers' weights and biases to ``grads``;
        return the gradient with respect to the input (None when the input is data)."""
        for i in reversed(range(len(self.steps))):
            module, *cached = self.steps[i]
            if isinstance(module, WEIGHT_LAYERS):
                x, weight, mask, patches = cached
                input_grad = i > 0 or not self.input_is_data
                grad_w, grad_b, g = _affine_backward(module, x, patches, weight, g, input_grad)
                grads[module.weight] = grad_w if mask is None else grad_w * mask
                if module.bias is not None:
                    grads[module.bias] = grad_b
            elif isinstance(module, nn.Flatten):
                g = g.view(cached[0])
            else:
                g = g * cached[0]
        return g


class _NetTrace:
    """A :class:`TwoStreamNet`'s forward pass at the current parameters, traced for tangent and backward
    passes."""

    def __init__(self, net: TwoStreamNet, inputs: list[torch.Tensor], patch_cache: dict):
        """``inputs``: the network's stream inputs, ``net._stream_inputs(obs)``."""
        self.streams = [_Trace(stream, x, True, patch_cache) for stream, x in zip(net.streams, inputs)]
        self.head = _Trace(net.head, torch.cat([s.output for s in self.streams], dim=-1), False)
        self.widths = [s.output.shape[-1] for s in self.streams]
        self.output = self.head.output

    def tangent(self, tangents: dict[nn.Parameter, torch.Tensor]) -> torch.Tensor:
        features = torch.cat([s.tangent(tangents, None) for s in self.streams], dim=-1)
        return self.head.tangent(tangents, features)

    def backward(self, g: torch.Tensor, grads: dict[nn.Parameter, torch.Tensor]) -> None:
        features = self.head.backward(g, grads)
        for stream, part in zip(self.streams, torch.split(features, self.widths, dim=-1)):
            stream.backward(part, grads)


class GaussNewtonFisher:
    """v -> F v for a :class:`GaussianPolicy` on a batch of observations, F the Hessian of the mean
    KL(old || pi_theta) at the current parameters theta = theta_old (see the module docstring).

    policy: a policy for which :func:`supports` holds. obs: the batch (the states the mean KL averages
    over). old: the policy's own distribution on ``obs`` at the current parameters, as TRPO's pi_old;
    its sigma gives M. params: the parameters v lives on, in the order of the flat vector (those that
    require grad; any other parameter is held fixed).

    The constructor runs one forward pass; each call then costs one tangent pass and one backward pass
    through both networks, over the activations of that forward pass.
    """

    def __init__(self, policy: GaussianPolicy, obs, old: Normal, params: list[nn.Parameter]):
        if not supports(policy):
            raise TypeError("GaussNewtonFisher needs a GaussianPolicy of Linear/Conv2d/ReLU/Tanh/Flatten layers "
                            "with its sparse-VD layers pruned or in eval mode; use trust_region.fisher_vector_product")
        self.params = params
        with torch.no_grad():
            mu_inputs, sigma_inputs = policy.mu._stream_inputs(obs), policy.sigma._stream_inputs(obs)
            # The two networks normalise the observation alike: share the tensors (and their patches).
            sigma_inputs = [m if torch.equal(m, s) else s for m, s in zip(mu_inputs, sigma_inputs)]
            patch_cache = {}
            self.mu = _NetTrace(policy.mu, mu_inputs, patch_cache)
            self.sigma = _NetTrace(policy.sigma, sigma_inputs, patch_cache)
            std = policy.min_std + F.softplus(self.sigma.output)
        if not (torch.allclose(self.mu.output, old.mean, rtol=1e-4, atol=1e-6)
                and torch.allclose(std, old.stddev, rtol=1e-4, atol=1e-6)):
            raise RuntimeError("GaussNewtonFisher's forward pass disagrees with policy.distribution(): "
                               "the two must compute the same mu and sigma")
        # d sigma / d (sigma network output), and M per output (1/N: the KL is a mean over the batch)
        self.dstd = torch.sigmoid(self.sigma.output)
        variance = old.variance.detach()
        self.m_mean, self.m_std = 1 / (variance * len(variance)), 2 / (variance * len(variance))

    @torch.no_grad()
    def __call__(self, v: torch.Tensor) -> torch.Tensor:
        """F v (no damping) as a flat vector in the order of ``params``."""
        pieces = torch.split(v, [p.numel() for p in self.params])
        tangents = {p: piece.view_as(p) for p, piece in zip(self.params, pieces)}
        grads = {}
        self.mu.backward(self.m_mean * self.mu.tangent(tangents), grads)
        self.sigma.backward(self.dstd * self.m_std * self.dstd * self.sigma.tangent(tangents), grads)
        return torch.cat([grads[p].reshape(-1) if p in grads else v.new_zeros(p.numel()) for p in self.params])
