"""The methods the experiments compare, as one table: each entry says everything the pipeline needs to know
about a way of pre-training the policy, so that adding a method is adding one entry.

An entry (:class:`Method`) answers five questions:

- **Layers**: ``variational`` -- whether mu and sigma are built of sparse variational dropout layers
  (eq. 4) or plain ones (:func:`vdtutorial.policy.make_policy`).
- **Loss**: :meth:`Method.penalty` -- the term added to the negative log-likelihood of behavioural cloning
  (eq. 3's KL for VD, ``l2 * sum(W^2)`` for L2, nothing for a method without one).
- **Pruning**: ``prunes`` -- whether weights with log alpha > 3 are dropped before RL (Section IV-A).
- **Start sigma**: ``spread_from`` -- under the start sigma "spread" (sigma fitted to a dropout model's
  predictive spread), which method's mean network gives the spread: None for the method's own (it must be
  variational), otherwise the name of the method whose network pre-trained alike it follows (L2 follows VD's).
  A fixed sigma or "demos" needs nothing of the method.
- **Picture**: ``label`` and ``colour`` of its curves.

``pretrains`` is False for the two entries that are no pre-training: "none" (RL from a fresh network, sigma
fixed) and "expert" (the IK expert's reference line, scored but not trained: ``finetuned`` False).

Register a new method with :func:`register` (an instance of :class:`Method` or of a subclass overriding
:meth:`Method.penalty`); the experiments, the plots and ``--methods`` then know it by its name. A method
registered in a running Python is known to that process only: run its experiments with one worker.

Taught in chapter 05.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from torch import Tensor, nn

from vdtutorial.vd import model_kl, pruned_fraction


@dataclass(frozen=True)
class CloningStep:
    """Where behavioural cloning is when a penalty is asked for: ``step`` of ``total_steps`` minibatch steps,
    ``n_train`` training samples, and the cloning's ``config`` (a :class:`~vdtutorial.pretrain.PretrainConfig`)."""

    step: int
    total_steps: int
    n_train: int
    config: object


@dataclass(frozen=True)
class Method:
    """One row of the table: the module docstring, "five questions". The base class adds no penalty: a method that
    only changes the layers, or pruning, needs no subclass."""

    name: str
    label: str
    colour: str
    variational: bool = False
    prunes: bool = False
    spread_from: str | None = "vd"
    pretrains: bool = True
    finetuned: bool = True

    def penalty(self, mu: nn.Module, at: CloningStep) -> Tensor | None:
        """The term added to the mean negative log-likelihood of a minibatch (None: nothing is added)."""
        return None

    def warmup_epochs(self, config) -> int:
        """Epochs at the start of cloning during which the objective itself still changes: early stopping on the
        held-out loss (``PretrainConfig.patience``) counts from there."""
        return 0

    def epoch_record(self, mu: nn.Module) -> dict:
        """What the per-epoch log of cloning records about the method beside the losses."""
        return {}


@dataclass(frozen=True)
class SparseVD(Method):
    """Sparse variational dropout: the KL of eqs. 1-3 to the log-uniform prior, divided by N (``kl_divisor``
    or the training split's size), weighted by beta rising linearly from 0 to 1 over the first ``beta_warmup``
    fraction of the steps (early on the data term shapes the weights before the KL pushes them to be dropped)."""

    def penalty(self, mu: nn.Module, at: CloningStep) -> Tensor:
        beta = min(1.0, at.step / max(1.0, at.config.beta_warmup * at.total_steps))
        return beta * model_kl(mu) / (at.config.kl_divisor or at.n_train)

    def warmup_epochs(self, config) -> int:
        return math.ceil(config.beta_warmup * config.epochs)

    def epoch_record(self, mu: nn.Module) -> dict:
        return {"weights_pruned": pruned_fraction(mu)}


@dataclass(frozen=True)
class WeightDecay(Method):
    """The paper's baseline: ``config.l2 * sum(W^2)`` over the weights of mu (biases excluded)."""

    def penalty(self, mu: nn.Module, at: CloningStep) -> Tensor:
        return at.config.l2 * sum((p**2).sum() for name, p in mu.named_parameters() if name.endswith("weight"))


#: The paper's two regularisers, no pre-training and the expert's reference line.
SHIPPED = (
    SparseVD("vd", "VD", "tab:blue", variational=True, prunes=True, spread_from=None),
    WeightDecay("l2", "L2", "tab:orange"),
    Method("none", "no pre-training", "tab:gray", spread_from=None, pretrains=False),
    Method("expert", "IK expert", "black", spread_from=None, pretrains=False, finetuned=False),
)
#: The table, by name, in the order of figures and legends: the shipped entries, then the registered ones.
METHODS: dict[str, Method] = {entry.name: entry for entry in SHIPPED}


def register(entry: Method) -> Method:
    """Add ``entry`` to the table, or replace an entry of the same name registered before (so that a notebook
    cell can be run again), and return it. The shipped entries cannot be replaced."""
    if entry.name in {shipped.name for shipped in SHIPPED} and entry not in SHIPPED:
        raise ValueError(f"{entry.name!r} is a shipped method: give yours another name")
    if entry.spread_from is not None and entry.spread_from not in METHODS:
        raise ValueError(f"{entry.name!r} follows the spread of {entry.spread_from!r}, which is not in the table")
    METHODS[entry.name] = entry
    return entry


def method(name: str) -> Method:
    """The entry called ``name`` (ValueError naming the table's methods for another name)."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"no method {name!r}: the methods are {', '.join(METHODS)}") from None


def pretraining_methods() -> tuple[str, ...]:
    """The names of the entries that pre-train, in the table's order."""
    return tuple(name for name, entry in METHODS.items() if entry.pretrains)


class _Labels(Mapping):
    """The table's labels by name, read at each look-up, so that a method registered later has its label too."""

    def __getitem__(self, name: str) -> str:
        return METHODS[name].label

    def __iter__(self) -> Iterator[str]:
        return iter(METHODS)

    def __len__(self) -> int:
        return len(METHODS)


#: Each method's label, by name (a live view of :data:`METHODS`).
METHOD_LABELS: Mapping[str, str] = _Labels()
