"""Reading the sparsity sparse VD produced: which weights and which neurons a network could drop
(:func:`sparsity_report`, the paper's Table I counts), from the network's wiring (:func:`graph`).

Wiring
    A hidden unit is prunable when all its incoming weights are pruned (dead-in) or all its outgoing
    weights are (dead-out). Telling which weights are a unit's outgoing ones needs the wiring: which
    layer's output units feed which columns of the next layer. :class:`Edge` lists describe it;
    :func:`chain` derives them for ``nn.Sequential`` stacks, and :func:`graph` for the policy's
    two-stream networks (or any module with a ``weight_edges()`` method).

Taught in chapter 04.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from vdtutorial.policy import GaussianPolicy, PolicyNet
from vdtutorial.vd import THRESHOLD, WEIGHT_LAYERS, SVDOLayer


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


def unit_count(layer: nn.Module) -> int:
    return layer.weight.shape[0]


def column_count(layer: nn.Module) -> int:
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
        if not flattened or column_count(dst) % unit_count(src):
            raise TypeError(f"{src!r} -> {dst!r} needs a Flatten and in_features divisible by the channels")
        return Edge(src, dst, repeat=column_count(dst) // unit_count(src), post=post)
    if column_count(dst) != unit_count(src):
        raise ValueError(f"size mismatch between {src!r} and {dst!r}")
    return Edge(src, dst, post=post)


def concat_edges(tails: list[tuple[nn.Module, tuple[nn.Module, ...]]], dst: nn.Module) -> list[Edge]:
    """Edges from the open ends of several streams (see :func:`chain`) into ``dst``, which reads their
    outputs concatenated in that order."""
    edges, offset = [], 0
    for src, post in tails:
        edges.append(Edge(src, dst, offset=offset, post=post))
        offset += unit_count(src)
    if offset != column_count(dst):
        raise ValueError(f"the streams give {offset} features but {dst!r} reads {column_count(dst)}")
    return edges


def _two_stream_edges(net: PolicyNet) -> list[Edge]:
    """The streams' own edges, and each stream's last weight layer into the head, which reads them concatenated."""
    edges, tails = [], []
    for stream in net.streams:
        stream_edges, tail = chain(stream)
        edges += stream_edges
        tails.append(tail)
    return edges + concat_edges(tails, net.head[0])


def graph(module: nn.Module) -> list[Edge]:
    """The edges of ``module``: a policy's two networks, a :class:`~vdtutorial.policy.PolicyNet`, a module
    with a ``weight_edges()`` method, or a Sequential."""
    if isinstance(module, GaussianPolicy):
        return _two_stream_edges(module.mu) + _two_stream_edges(module.sigma)
    if isinstance(module, PolicyNet):
        return _two_stream_edges(module)
    if hasattr(module, "weight_edges"):
        return module.weight_edges()
    if isinstance(module, nn.Sequential):
        return chain(module)[0]
    raise TypeError(
        f"cannot tell how the layers of {type(module).__name__} are wired: use an nn.Sequential "
        "or give the module a weight_edges() method returning Edge objects"
    )


def kept_weights(layer: nn.Module, threshold: float = THRESHOLD) -> torch.Tensor:
    """Kept weights of any weight layer: every weight of a plain layer is kept."""
    if isinstance(layer, SVDOLayer):
        return layer.keep_mask(threshold)
    return torch.ones_like(layer.weight, dtype=torch.bool)


def dead_units(layers, edges, masks) -> dict[nn.Module, tuple[torch.Tensor, torch.Tensor]]:
    """Per layer, boolean vectors over its output units: (all incoming weights pruned, all outgoing
    weights pruned). Only layers whose units feed another layer (hidden layers) are listed."""
    live_columns = {layer: masks[layer].transpose(0, 1).reshape(column_count(layer), -1).any(1) for layer in layers}
    dead_out = {}
    for e in edges:
        n = unit_count(e.src)
        read = live_columns[e.dst][e.offset : e.offset + n * e.repeat].view(n, e.repeat).any(1)
        dead_out[e.src] = dead_out.get(e.src, torch.ones(n, dtype=torch.bool, device=read.device)) & ~read
    return {layer: (~masks[layer].reshape(unit_count(layer), -1).any(1), d) for layer, d in dead_out.items()}


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
        return sum(getattr(layer, field) for layer in self.layers)

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
        rows = [
            f"{'layer':<24}{'weights':>10}{'% pruned':>9}{'units':>7}{'dead-in':>9}{'dead-out':>10}{'units pruned':>14}"
        ]
        for layer in self.layers:
            pruned = layer.pruned_weights / layer.weights
            rows.append(
                f"{layer.name:<24}{layer.weights:>10}{pruned:>9.1%}{layer.hidden_units:>7}"
                f"{layer.dead_in:>9}{layer.dead_out:>10}{layer.dead:>14}"
            )
        rows.append(
            f"weights pruned {self.weight_fraction:.1%} (compression x{self.compression:.1f}); neurons pruned "
            f"{self.neuron_fraction:.1%} (dead-in {self.neuron_fraction_in:.1%}, dead-out "
            f"{self.neuron_fraction_out:.1%}); threshold log alpha > {self.threshold:g}"
        )
        return "\n".join(rows)


@torch.no_grad()
def sparsity_report(module: nn.Module, threshold: float = THRESHOLD) -> SparsityReport:
    """Pruned weights and neurons of ``module`` if weights with log alpha > ``threshold`` were dropped
    (already pruned layers report their frozen mask). Plain layers count as fully kept."""
    names = {m: name or type(m).__name__ for name, m in module.named_modules()}
    layers = weight_layers(module)
    masks = {layer: kept_weights(layer, threshold) for layer in layers}
    dead = dead_units(layers, graph(module), masks)
    rows = []
    for layer in layers:
        row = dict(
            name=names[layer],
            weights=masks[layer].numel(),
            pruned_weights=int((~masks[layer]).sum()),
            hidden_units=0,
            dead_in=0,
            dead_out=0,
            dead=0,
        )
        if layer in dead:
            dead_in, dead_out = dead[layer]
            row.update(
                hidden_units=unit_count(layer),
                dead_in=int(dead_in.sum()),
                dead_out=int(dead_out.sum()),
                dead=int((dead_in | dead_out).sum()),
            )
        rows.append(LayerSparsity(**row))
    return SparsityReport(rows, threshold)
