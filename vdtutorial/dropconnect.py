"""Binary dropout on the weights of a plain network (DropConnect: Wan et al., 2013, "Regularization of Neural
Networks using DropConnect"), during behavioural cloning only: the regulariser that keeps sparse VD's multiplicative
noise on each weight but neither its learned per-weight variances nor its pruning.

The noise
    Each weight w is multiplied by an independent Bernoulli mask m ~ B(1 - p) and rescaled by 1 / (1 - p), so the
    weight the layer applies, w m / (1 - p), has mean w and variance w^2 p / (1 - p): multiplicative noise of
    variance alpha = p / (1 - p), the alpha of Gaussian dropout at the same rate (Kingma, Salimans & Welling 2015,
    "Variational Dropout and the Local Reparameterization Trick"; the correspondence :mod:`vdtutorial.vd` states).
    A fully connected layer draws one mask per example, as VD's local reparameterisation draws independent noise per
    example; a convolution draws one mask per minibatch, since a mask per example would need a convolution per
    example. The objective is the same either way (its expectation over the masks); only the gradient's noise differs.
    In eval mode the layer is the plain one: deterministic, every weight kept.

Where the masks live
    Only inside :func:`dropconnect`, a ``with`` block around the cloning. Its layers hold the plain layers' own
    parameters under the same names, so the optimiser, a state_dict taken inside the block and the checkpoint all
    see the plain network, and RL fine-tunes that plain network as it is (no noise, no mask).

Not taught in a chapter: it serves the ablations of VD planned in docs/plan-ablations-and-image-fig5.md.
"""

from __future__ import annotations

from contextlib import contextmanager

import torch
from torch import nn


def _check_rate(rate: float) -> float:
    rate = float(rate)
    if not 0 <= rate < 1:
        raise ValueError(f"a dropout rate is in [0, 1), got {rate!r}")
    return rate


class DropConnect(nn.Module):
    """A plain ``nn.Linear`` or ``nn.Conv2d`` with Bernoulli masks on its weights in training mode
    (module docstring, "The noise"). ``weight`` and ``bias`` are the plain layer's Parameter objects; the plain
    layer itself is kept unregistered, to be put back by :func:`dropconnect`."""

    def __init__(self, layer: nn.Linear | nn.Conv2d, rate: float):
        super().__init__()
        if not isinstance(layer, (nn.Linear, nn.Conv2d)):
            raise TypeError(f"DropConnect wraps nn.Linear or nn.Conv2d, got {type(layer).__name__}")
        self.rate = _check_rate(rate)
        self.weight = layer.weight
        self.bias = layer.bias
        object.__setattr__(self, "plain", layer)  # not a submodule: its parameters are already registered here

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.rate == 0:
            return self.plain(x)
        keep = 1.0 - self.rate
        if isinstance(self.plain, nn.Conv2d):
            mask = torch.bernoulli(torch.full_like(self.weight, keep))
            return self.plain._conv_forward(x, self.weight * mask / keep, self.bias)
        rows = x.reshape(-1, x.shape[-1])
        mask = torch.bernoulli(torch.full((rows.shape[0], *self.weight.shape), keep, device=x.device))
        out = torch.einsum("ni,noi->no", rows, self.weight * mask) / keep
        if self.bias is not None:
            out = out + self.bias
        return out.reshape(*x.shape[:-1], out.shape[-1])

    def extra_repr(self) -> str:
        return f"{self.plain.extra_repr()}, rate={self.rate:g}"


@contextmanager
def dropconnect(net: nn.Module, rate: float):
    """Within the block, every plain ``nn.Linear`` and ``nn.Conv2d`` inside ``net`` is a :class:`DropConnect` at
    ``rate`` (masks in training mode only); afterwards the plain layers are back, holding what was learnt."""
    rate = _check_rate(rate)
    plain = [
        (parent, name, child)
        for parent in net.modules()
        for name, child in parent.named_children()
        if type(child) in (nn.Linear, nn.Conv2d)
    ]
    for parent, name, child in plain:
        setattr(parent, name, DropConnect(child, rate))
    try:
        yield net
    finally:
        for parent, name, child in plain:
            setattr(parent, name, child)
