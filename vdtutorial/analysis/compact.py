"""Exploiting the sparsity: :func:`compact` removes pruned neurons physically, giving a smaller plain
network with the same eval-mode outputs (a dead-in unit's constant folds into the next layer's bias).

Taught in chapter 04.
"""

from __future__ import annotations

import copy
from collections import defaultdict

import torch
from torch import nn

from vdtutorial.analysis.sparsity import (
    Edge,
    chain,
    column_count,
    dead_units,
    graph,
    kept_weights,
    unit_count,
    weight_layers,
)
from vdtutorial.policy import PolicyNet


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
        new = nn.Conv2d(
            weight.shape[1],
            weight.shape[0],
            layer.kernel_size,
            stride=layer.stride,
            padding=layer.padding,
            bias=bias is not None,
        )
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
    masks = {layer: kept_weights(layer) for layer in layers}
    weights = {layer: layer.weight * masks[layer] for layer in layers}
    dead = dead_units(layers, edges, masks)
    consumers, producers = defaultdict(list), defaultdict(list)
    for e in edges:
        consumers[e.src].append(e)
        producers[e.dst].append(e)
    keep = {}
    for layer in layers:
        keep[layer] = torch.ones(unit_count(layer), dtype=torch.bool)
        if layer in dead:
            dead_in, dead_out = dead[layer]
            foldable = all(_fold_is_exact(e.dst) for e in consumers[layer])
            keep[layer] = ~(dead_out | (dead_in & foldable))
    new = {}
    for layer in layers:
        columns = torch.ones(column_count(layer), dtype=torch.bool)
        constants = torch.zeros(column_count(layer))
        for e in producers[layer]:
            n = unit_count(e.src)
            bias = e.src.bias if e.src.bias is not None else torch.zeros(n)
            value = nn.Sequential(*e.post)(bias.view(1, n)).view(n)
            span = slice(e.offset, e.offset + n * e.repeat)
            columns[span] = keep[e.src].repeat_interleave(e.repeat)
            constants[span] = torch.where(keep[e.src], 0.0, value).repeat_interleave(e.repeat)
        w = weights[layer]
        fold = w.reshape(*w.shape[:2], -1).sum(-1) @ constants
        bias = None
        if layer.bias is not None or bool(fold.any()):
            bias = (layer.bias if layer.bias is not None else 0.0) + fold
            bias = bias[keep[layer]]
        new[layer] = _plain_like(layer, w[keep[layer]][:, columns], bias)
    return new


def rebuild_sequential(seq: nn.Sequential, replacements: dict[nn.Module, nn.Module]) -> nn.Sequential:
    """Copy of ``seq`` with its weight layers swapped for their ``replacements``."""
    return nn.Sequential(*(replacements[m] if m in replacements else copy.deepcopy(m) for m in seq))


def compact(module: nn.Module) -> nn.Module:
    """Plain network with pruned neurons physically removed; same outputs as ``module`` in eval mode.

    Works for ``nn.Sequential`` stacks of Linear / Conv2d (plain or sparse VD), elementwise activations and
    ``Flatten`` (a removed channel removes its H * W columns of the following Linear layer), and for
    the policy's :class:`vdtutorial.policy.PolicyNet` networks, and modules with their own ``compact()`` method. The
    input and output sizes are unchanged; hidden layers shrink.
    """
    if isinstance(module, nn.Sequential):
        return rebuild_sequential(module, compact_layers(module, chain(module)[0]))
    if isinstance(module, PolicyNet):
        replacements = compact_layers(module, graph(module))
        new = copy.deepcopy(module)
        new.streams = nn.ModuleList(rebuild_sequential(stream, replacements) for stream in module.streams)
        new.head = rebuild_sequential(module.head, replacements)
        return new
    if hasattr(module, "compact"):
        return module.compact()
    raise TypeError(f"compact() handles nn.Sequential or modules with a compact() method, not {type(module).__name__}")
