"""The paper's policy, evaluated faster on a batch it reads many times: the same numbers as
:class:`vdtutorial.policy.GaussianPolicy`, bit for bit, with two speed-ups that TRPO's update profits from.

Inputs prepared once
    TRPO's update evaluates the policy on one batch about a dozen times (the surrogate, the Fisher products,
    the line search). :func:`prepare_inputs` normalises the batch once, for both networks when they
    normalise alike (:class:`PreparedObs`); for the image policy the normalisation alone was a fifth of the
    update's time (docs/results.md, "Fine-tuning throughput").
Fused first convolutions
    mu's and sigma's first convolutions read the same image. :func:`fused_conv2d` runs them as one
    convolution with both filter banks stacked: each output channel is still one filter's dot product with
    the same patches, so the outputs are the separate convolutions' outputs, but the image, the network's
    largest tensor, is read once instead of twice.

:class:`FastGaussianPolicy` is a :class:`~vdtutorial.policy.GaussianPolicy` that uses both; :func:`fast_policy`
makes one around a policy's own networks (same parameters, same ``state_dict``). The experiments fine-tune with it
and with :func:`vdtutorial.fast.fisher.gauss_newton_fvp`, which reads the same prepared inputs.

Taught in chapter 06b.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal

from vdtutorial.policy import GaussianPolicy, PolicyNet, obs_to_tensor
from vdtutorial.vd import SVDOLayer


def applied_weight(layer: nn.Module) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The weight a deterministic forward pass of ``layer`` applies, and the 0/1 mask it was multiplied
    by (None: a plain layer, no mask); for a sparse-VD layer that is pruned or in eval mode."""
    if isinstance(layer, SVDOLayer):
        mask = layer.keep_mask().to(layer.weight.dtype)
        return layer.weight * mask, mask
    return layer.weight, None


def conv_geometry(layer: nn.Module) -> tuple[tuple, tuple, tuple, int]:
    """stride, padding, dilation, groups of a plain or sparse-VD convolution."""
    if isinstance(layer, nn.Conv2d):
        return layer.stride, layer.padding, layer.dilation, layer.groups
    return layer.stride, layer.padding, (1, 1), 1


def fusable_convolutions(layers) -> bool:
    """True when the convolutions ``layers`` can run on one input as a single convolution
    (:func:`fused_conv2d`): same kernel size and geometry, zero padding given as numbers, no groups, and
    deterministic (a sparse-VD layer pruned or in eval mode)."""
    for layer in layers:
        if isinstance(layer, SVDOLayer):
            if layer.weight.dim() != 4 or (layer.training and not layer.pruned):
                return False
        elif not isinstance(layer, nn.Conv2d) or layer.padding_mode != "zeros" or isinstance(layer.padding, str):
            return False
    first = layers[0]
    return (
        all(
            conv_geometry(layer) == conv_geometry(first) and layer.weight.shape[1:] == first.weight.shape[1:]
            for layer in layers
        )
        and conv_geometry(first)[3] == 1
    )


def fused_conv2d(
    layers, x: torch.Tensor, weights: list[torch.Tensor], biases: list[torch.Tensor | None]
) -> list[torch.Tensor]:
    """The convolutions ``layers`` (:func:`fusable_convolutions`) of the same input ``x`` with the given
    weights and biases, computed as one convolution with all their filters stacked, then split per layer."""
    stride, padding, dilation, _ = conv_geometry(layers[0])
    if any(b is None for b in biases):
        biases = [
            torch.zeros(w.shape[0], dtype=w.dtype, device=w.device) if b is None else b for w, b in zip(weights, biases)
        ]
    y = F.conv2d(x, torch.cat(weights), torch.cat(biases), stride, padding, dilation)
    return list(y.split([w.shape[0] for w in weights], dim=1))


@dataclass(frozen=True)
class PreparedObs:
    """A batch of observations turned into the stream inputs of ``mu`` and of ``sigma`` (the same list
    when the two networks normalise alike), by :func:`prepare_inputs`."""

    mu: list[torch.Tensor]
    sigma: list[torch.Tensor]


def same_inputs(net: PolicyNet, other: PolicyNet) -> bool:
    """True when ``other`` turns every observation into the same stream inputs as ``net`` (same kind and
    normalisation), so that both can read one prepared copy."""
    if net.kind != other.kind:
        return False
    mine = dict(net.named_buffers(recurse=False))
    theirs = dict(other.named_buffers(recurse=False))
    return mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)


def prepare_inputs(policy: GaussianPolicy, obs) -> PreparedObs:
    """The networks' inputs for a batch of observations, normalised once for both networks; a
    :class:`PreparedObs` passes through unchanged."""
    if isinstance(obs, PreparedObs):
        return obs
    obs = obs_to_tensor(obs)
    mu_inputs = policy.mu.stream_inputs(obs)
    sigma_inputs = mu_inputs if same_inputs(policy.mu, policy.sigma) else policy.sigma.stream_inputs(obs)
    return PreparedObs(mu_inputs, sigma_inputs)


def fused_first_layers(policy: GaussianPolicy, inputs: PreparedObs) -> list[nn.Module] | None:
    """[mu's, sigma's] first convolution when they read the same prepared image and can run as one
    (:func:`fused_conv2d`); None otherwise (the networks then run apart)."""
    if policy.mu.kind != "rgbd" or inputs.mu[0] is not inputs.sigma[0]:
        return None
    firsts = [policy.mu.streams[0][0], policy.sigma.streams[0][0]]
    return firsts if fusable_convolutions(firsts) else None


def net_from_inputs(net: PolicyNet, inputs: list[torch.Tensor], first_scene_output: torch.Tensor | None = None):
    """``net`` on stream inputs already made (:func:`prepare_inputs`); ``first_scene_output``, when given, is
    the scene stream's first layer already applied to ``inputs[0]`` (:func:`fused_conv2d`)."""
    scene, *others = net.streams
    if first_scene_output is None:
        features = [scene(inputs[0])]
    else:
        x = first_scene_output
        for module in itertools.islice(scene, 1, None):
            x = module(x)
        features = [x]
    features += [stream(x) for stream, x in zip(others, inputs[1:])]
    return net.head(torch.cat(features, dim=-1))


def _batch_tensors(obs) -> tuple[tuple[torch.Tensor, int], ...] | None:
    """The tensors of a batch of observations with their version counters (which in-place writes advance), or None
    when ``obs`` is not made of tensors that track versions (nothing is then reused)."""
    tensors = [obs] if isinstance(obs, torch.Tensor) else list(obs.values()) if isinstance(obs, dict) else []
    if not tensors or not all(isinstance(t, torch.Tensor) and not t.is_inference() for t in tensors):
        return None
    return tuple((t, t._version) for t in tensors)


def _same_batch(a, b) -> bool:
    return len(a) == len(b) and all(x is y and vx == vy for (x, vx), (y, vy) in zip(a, b))


class FastGaussianPolicy(GaussianPolicy):
    """A :class:`~vdtutorial.policy.GaussianPolicy` built around the modules of another one (:func:`fast_policy`):
    the same parameters, buffers and ``state_dict`` keys, and the same distribution bit for bit, computed with the
    inputs of the batch it last read kept (:meth:`prepare`) and its first convolutions fused.

    TRPO's update hands the policy the same batch object about a dozen times (the surrogate, the Fisher products,
    the line search): the first call prepares its inputs, the others reuse them. The batch is recognised by its
    tensors' identity and version counters, so a tensor written in place is prepared afresh."""

    def __init__(self, policy: GaussianPolicy):
        nn.Module.__init__(self)  # not GaussianPolicy's: the networks are ``policy``'s own, not new ones
        self.config = policy.config
        self.min_std = policy.min_std
        self.mu = policy.mu
        self.sigma = policy.sigma
        self.train(policy.training)
        self._last_batch: tuple[tuple, PreparedObs] | None = None

    @classmethod
    def from_config(cls, config: dict) -> "FastGaussianPolicy":
        return cls(GaussianPolicy.from_config(config))

    def prepare(self, obs) -> PreparedObs:
        """:func:`prepare_inputs` of ``obs``, reused when ``obs`` is the batch the last call prepared."""
        if isinstance(obs, PreparedObs):
            return obs
        tensors = _batch_tensors(obs)
        if tensors is not None and self._last_batch is not None and _same_batch(tensors, self._last_batch[0]):
            return self._last_batch[1]
        inputs = prepare_inputs(self, obs)
        self._last_batch = None if tensors is None else (tensors, inputs)
        return inputs

    def outputs(self, obs) -> tuple[torch.Tensor, torch.Tensor]:
        """mu and the sigma network's output before the softplus, for a batch of observations or its
        :meth:`prepare` d inputs."""
        inputs = self.prepare(obs)
        firsts = fused_first_layers(self, inputs)
        if firsts is None:
            return net_from_inputs(self.mu, inputs.mu), net_from_inputs(self.sigma, inputs.sigma)
        weights = [applied_weight(layer)[0] for layer in firsts]
        biases = [layer.bias for layer in firsts]
        mu_first, sigma_first = fused_conv2d(firsts, inputs.mu[0], weights, biases)
        return net_from_inputs(self.mu, inputs.mu, mu_first), net_from_inputs(self.sigma, inputs.sigma, sigma_first)

    def distribution(self, obs) -> Normal:
        mu, sigma_output = self.outputs(obs)
        return Normal(mu, self.min_std + F.softplus(sigma_output))


def fast_policy(policy: GaussianPolicy) -> FastGaussianPolicy:
    """A :class:`FastGaussianPolicy` that shares ``policy``'s networks: training one trains the other, and either's
    ``state_dict`` loads into both. ``policy`` itself is left as it is; a fast policy is returned as it is."""
    if isinstance(policy, FastGaussianPolicy):
        return policy
    if type(policy) is not GaussianPolicy:  # a subclass may compute its distribution otherwise
        raise TypeError(f"fast_policy needs a GaussianPolicy, got {type(policy).__name__}")
    return FastGaussianPolicy(policy)
