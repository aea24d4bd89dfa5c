r"""The exact Fisher-vector product of the Gaussian policy, computed in Gauss-Newton form.

TRPO's conjugate gradient needs F v about a dozen times per update, where F is the Hessian of the mean
KL(pi_old || pi_theta) at theta = theta_old (:mod:`vdtutorial.trpo`, step 4). The generic way
(:func:`vdtutorial.trust_region.double_backward_fvp`, TRPO's default and the one chapter 06 teaches) differentiates
the KL twice with autograd. For the paper's policy pi(a | s) = N(mu(s), diag(sigma(s)^2)) the same matrix has
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

Taught in chapter 06b.
"""

from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal

from vdtutorial.fast.policy import (
    FastGaussianPolicy,
    applied_weight,
    conv_geometry,
    fused_conv2d,
    fused_first_layers,
    prepare_inputs,
)
from vdtutorial.policy import GaussianPolicy, PolicyNet
from vdtutorial.trust_region import double_backward_fvp
from vdtutorial.vd import WEIGHT_LAYERS, SVDOLayer

#: The parameter-free modules the products let weight layers (vd.WEIGHT_LAYERS) be mixed with.
ACTIVATIONS = (nn.ReLU, nn.Tanh, nn.Flatten)


def supports(policy: nn.Module) -> bool:
    """True when :class:`GaussNewtonFisher` computes the Fisher-vector products of ``policy``.

    Pruning (chapter 04) enters both passes the way it enters the forward pass, as the weight's 0/1 mask:
    the product along a pruned weight, and along a parameter that is frozen or that the outputs do not
    depend on, is exactly 0.

    Supported: :class:`vdtutorial.policy.GaussianPolicy` whose networks are built from plain or sparse-VD
    Linear / Conv2d layers, ReLU, Tanh and Flatten (every network :func:`vdtutorial.policy.make_policy`
    builds), with sparse-VD layers pruned or in eval mode (in train mode an unpruned sparse-VD layer is
    random, and TRPO's policy must be deterministic). :func:`supports` says whether a policy qualifies;
    :func:`gauss_newton_fvp` falls back to the double backward for any other policy.
    """
    if type(policy) not in (GaussianPolicy, FastGaussianPolicy):  # another subclass may change distribution()
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


def _apply(layer: nn.Module, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``layer``'s affine map with the given weight and bias (a tangent pass uses it with tangents)."""
    if isinstance(layer, SVDOLayer):
        return layer._op(x, weight, bias)
    if isinstance(layer, nn.Conv2d):
        return layer._conv_forward(x, weight, bias)
    return F.linear(x, weight, bias)


def _affine_backward(layer: nn.Module, x: torch.Tensor, weight: torch.Tensor, g: torch.Tensor, input_grad: bool):
    """Gradients of <g, layer(x)> with respect to the weight the layer applies, its bias and (when
    ``input_grad``) its input x."""
    if weight.dim() == 2:  # fully connected
        return g.T @ x, g.sum(0), (g @ weight if input_grad else None)
    stride, padding, dilation, groups = conv_geometry(layer)
    grad_x, grad_w, grad_b = torch.ops.aten.convolution_backward(
        g, x, weight, [weight.shape[0]], stride, padding, dilation, False, [0, 0], groups, [input_grad, True, True]
    )
    return grad_w, grad_b, grad_x


class _Trace:
    """One forward pass through a ``nn.Sequential`` of weight layers and elementwise activations,
    keeping what the tangent and backward passes need: each weight layer's input and applied weight,
    each activation's derivative at its input, each Flatten's input shape."""

    def __init__(self, seq, x: torch.Tensor, input_is_data: bool):
        """``seq``: the modules in order; ``input_is_data``: ``x`` does not depend on any parameter."""
        self.input_is_data = input_is_data
        self.steps = []
        for module in seq:
            if isinstance(module, WEIGHT_LAYERS):
                weight, mask = applied_weight(module)
                self.steps.append((module, x, weight, mask))
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
                x, weight, mask = cached
                dw = tangents.get(module.weight)
                db = tangents.get(module.bias)
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
                x, weight, mask = cached
                input_grad = i > 0 or not self.input_is_data
                grad_w, grad_b, g = _affine_backward(module, x, weight, g, input_grad)
                grads[module.weight] = grad_w if mask is None else grad_w * mask
                if module.bias is not None:
                    grads[module.bias] = grad_b
            elif isinstance(module, nn.Flatten):
                g = g.view(cached[0])
            else:
                g = g * cached[0]
        return g


def _unfold(x: torch.Tensor, kernel: tuple[int, int], stride, padding, dilation) -> torch.Tensor:
    """``F.unfold(x, kernel, dilation, padding, stride)``, the patches (N, C * kh * kw, positions), copied
    out of a strided view of x: the same numbers, faster than ``F.unfold`` on a TRPO batch of images
    (docs/results.md, "The Gauss-Newton Fisher's form")."""
    if any(padding):
        x = F.pad(x, (padding[1], padding[1], padding[0], padding[0]))
    n, c, height, width = x.shape
    rows = (height - dilation[0] * (kernel[0] - 1) - 1) // stride[0] + 1
    cols = (width - dilation[1] * (kernel[1] - 1) - 1) // stride[1] + 1
    s_n, s_c, s_h, s_w = x.stride()
    view = x.as_strided(
        (n, c, kernel[0], kernel[1], rows, cols),
        (s_n, s_c, dilation[0] * s_h, dilation[1] * s_w, stride[0] * s_h, stride[1] * s_w),
    )
    return view.reshape(n, c * kernel[0] * kernel[1], rows * cols)


class _FirstConvolutions:
    """mu's and sigma's first convolutions, which read the same image, traced as one
    (:func:`vdtutorial.fast.policy.fused_conv2d`). Their input is data, so the backward pass needs only the
    weight gradients: one batched matrix product per network with the image's patches, unfolded once
    per update for both (:class:`GaussNewtonFisher`, "Their two weight gradients stay two matrix products")."""

    def __init__(self, layers: list[nn.Module], image: torch.Tensor):
        self.layers = layers
        self.image = image
        self.weights, self.masks = zip(*(applied_weight(layer) for layer in layers))
        self.outputs = fused_conv2d(layers, image, self.weights, [layer.bias for layer in layers])
        self.patches = _unfold(image, self.weights[0].shape[2:], *conv_geometry(layers[0])[:3])

    def tangent(self, tangents: dict[nn.Parameter, torch.Tensor]) -> list[torch.Tensor]:
        """d output of each layer along ``tangents`` (the image does not move)."""
        dws = []
        for layer, weight, mask in zip(self.layers, self.weights, self.masks):
            dw = tangents.get(layer.weight)
            dws.append(torch.zeros_like(weight) if dw is None else dw if mask is None else dw * mask)
        dbs = [None if layer.bias is None else tangents.get(layer.bias) for layer in self.layers]
        return fused_conv2d(self.layers, self.image, dws, dbs)

    def backward(self, gs: list[torch.Tensor], grads: dict[nn.Parameter, torch.Tensor]) -> None:
        """Add the gradients of sum_i <gs[i], output i> with respect to the layers' weights and biases."""
        patches = self.patches.transpose(1, 2)
        for layer, weight, mask, g in zip(self.layers, self.weights, self.masks, gs):
            n, channels = g.shape[:2]
            grad_weight = torch.bmm(g.reshape(n, channels, -1), patches).sum(0).view_as(weight)
            grads[layer.weight] = grad_weight if mask is None else grad_weight * mask
            if layer.bias is not None:
                grads[layer.bias] = g.sum((0, 2, 3))


class _NetTrace:
    """A :class:`PolicyNet`'s forward pass at the current parameters, traced for tangent and backward
    passes."""

    def __init__(self, net: PolicyNet, inputs: list[torch.Tensor], first_output: torch.Tensor | None = None):
        """``inputs``: the network's stream inputs (:func:`vdtutorial.fast.policy.prepare_inputs`);
        ``first_output``: the scene stream's first layer already applied (by :class:`_FirstConvolutions`),
        or None to trace the scene stream whole."""
        scene, *others = net.streams
        if first_output is None:
            self.streams = [_Trace(scene, inputs[0], True)]
        else:
            self.streams = [_Trace(list(scene)[1:], first_output, False)]
        self.streams += [_Trace(stream, x, True) for stream, x in zip(others, inputs[1:])]
        self.head = _Trace(net.head, torch.cat([s.output for s in self.streams], dim=-1), False)
        self.widths = [s.output.shape[-1] for s in self.streams]
        self.output = self.head.output

    def tangent(
        self, tangents: dict[nn.Parameter, torch.Tensor], first_tangent: torch.Tensor | None = None
    ) -> torch.Tensor:
        """d output along ``tangents``; ``first_tangent``: that of the first layer traced apart, if any."""
        features = [self.streams[0].tangent(tangents, first_tangent)]
        features += [s.tangent(tangents, None) for s in self.streams[1:]]
        return self.head.tangent(tangents, torch.cat(features, dim=-1))

    def backward(self, g: torch.Tensor, grads: dict[nn.Parameter, torch.Tensor]) -> torch.Tensor | None:
        """Add the gradients of <g, output> to ``grads``; return the gradient with respect to the output of
        the first layer traced apart (None when the scene stream was traced whole)."""
        features = self.head.backward(g, grads)
        parts = torch.split(features, self.widths, dim=-1)
        return [stream.backward(part, grads) for stream, part in zip(self.streams, parts)][0]


class GaussNewtonFisher:
    """v -> F v for a :class:`GaussianPolicy` on a batch of observations, F the Hessian of the mean
    KL(old || pi_theta) at the current parameters theta = theta_old (module docstring, "F = J^T M J").

    policy: a policy for which :func:`supports` holds. obs: the batch (the states the mean KL averages
    over). old: the policy's own distribution on ``obs`` at the current parameters, as TRPO's pi_old;
    its sigma gives M. params: the parameters v lives on, in the order of the flat vector (those that
    require grad; any other parameter is held fixed).

    The constructor runs one forward pass; each call then costs one tangent pass and one backward pass
    through both networks, over the activations of that forward pass.

    Why both passes are written out here instead of left to autograd. The double backward (and the
    "double-vjp" trick that gets J v from two backward passes) goes through the convolutions'
    double-backward kernels, which also compute terms nobody needs (for the first convolution, a transposed
    convolution back onto the image); forward-mode AD (``torch.func.jvp``) recomputes the whole forward pass,
    input normalisation included, for every v; ``torch.func.linearize`` avoids that but traces the networks
    again at every update. And the weight gradient of the first convolution, the largest layer, is cheaper as
    one batched matrix product with the image patches, unfolded once per update, than with
    ``convolution_backward``. The costs of each way on the rgbd policy: docs/results.md, "The Gauss-Newton
    Fisher's form".

    mu's and sigma's first convolutions read the same image (:func:`vdtutorial.fast.policy.prepare_inputs`
    normalises it once for both): the forward and tangent passes run them as one convolution with both
    filter banks (:func:`vdtutorial.fast.policy.fused_conv2d`, bit for bit the same outputs), and the patches are
    unfolded once for both. Their two weight gradients stay two matrix products: one product with both
    filter banks would read the patches once, but it sums in another order, and conjugate gradient magnifies
    that last-bit difference within one update; every speed-up here keeps TRPO's numbers bit for bit
    (tests/test_regeneration.py).
    """

    def __init__(self, policy: GaussianPolicy, obs, old: Normal, params: list[nn.Parameter]):
        if not supports(policy):
            raise TypeError(
                "GaussNewtonFisher needs a GaussianPolicy of Linear/Conv2d/ReLU/Tanh/Flatten layers "
                "with its sparse-VD layers pruned or in eval mode; use trust_region.double_backward_fvp"
            )
        self.params = params
        with torch.no_grad():
            inputs = policy.prepare(obs) if isinstance(policy, FastGaussianPolicy) else prepare_inputs(policy, obs)
            firsts = fused_first_layers(policy, inputs)
            self.first = None if firsts is None else _FirstConvolutions(firsts, inputs.mu[0])
            first_outputs = [None, None] if self.first is None else self.first.outputs
            self.mu = _NetTrace(policy.mu, inputs.mu, first_outputs[0])
            self.sigma = _NetTrace(policy.sigma, inputs.sigma, first_outputs[1])
            std = policy.min_std + F.softplus(self.sigma.output)
        if not (
            torch.allclose(self.mu.output, old.mean, rtol=1e-4, atol=1e-6)
            and torch.allclose(std, old.stddev, rtol=1e-4, atol=1e-6)
        ):
            raise RuntimeError(
                "GaussNewtonFisher's forward pass disagrees with policy.distribution(): "
                "the two must compute the same mu and sigma"
            )
        # d sigma / d (sigma network output), and M per output (1/N: the KL is a mean over the batch)
        self.dstd = torch.sigmoid(self.sigma.output)
        variance = old.variance.detach()
        self.m_mean = 1 / (variance * len(variance))
        self.m_std = 2 / (variance * len(variance))

    @torch.no_grad()
    def __call__(self, v: torch.Tensor) -> torch.Tensor:
        """F v (no damping) as a flat vector in the order of ``params``."""
        pieces = torch.split(v, [p.numel() for p in self.params])
        tangents = {p: piece.view_as(p) for p, piece in zip(self.params, pieces)}
        grads = {}
        first_tangents = [None, None] if self.first is None else self.first.tangent(tangents)
        mu_tangent = self.mu.tangent(tangents, first_tangents[0])
        sigma_tangent = self.sigma.tangent(tangents, first_tangents[1])
        g_mu = self.mu.backward(self.m_mean * mu_tangent, grads)
        g_sigma = self.sigma.backward(self.dstd * self.m_std * self.dstd * sigma_tangent, grads)
        if self.first is not None:
            self.first.backward([g_mu, g_sigma], grads)
        return torch.cat([grads[p].reshape(-1) if p in grads else v.new_zeros(p.numel()) for p in self.params])


def gauss_newton_fvp(
    policy: nn.Module, params: list[nn.Parameter], obs, old: Normal, damping: float, dist: Normal | None = None
) -> Callable[[torch.Tensor], torch.Tensor]:
    """v -> (F + damping * I) v, with the signature of :func:`vdtutorial.trust_region.double_backward_fvp`: pass it
    as ``TRPO(fvp=gauss_newton_fvp)``. For a policy that :func:`supports` accepts, in Gauss-Newton form
    (:class:`GaussNewtonFisher`, which runs its own forward pass: ``dist`` is not needed); for any other policy,
    the double backward itself, the same matrix by the generic route."""
    if not supports(policy):
        return double_backward_fvp(policy, params, obs, old, damping, dist)
    product = GaussNewtonFisher(policy, obs, old, params)
    return lambda v: product(v) + damping * v
