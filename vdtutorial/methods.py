"""The methods the experiments compare, as one table: each entry says everything the pipeline needs to know
about a way of pre-training the policy, so that adding a method is adding one entry.

An entry (:class:`Method`) answers these questions:

- **Layers**: ``variational`` -- whether mu and sigma are built of sparse variational dropout layers
  (eq. 4) or plain ones (:func:`vdtutorial.policy.make_policy`).
- **Loss**: :meth:`Method.penalty` -- the term added to the negative log-likelihood of behavioural cloning
  (eq. 3's KL for VD, ``l2 * sum(W^2)`` for L2, nothing for a method without one).
- **Noise while cloning**: :meth:`Method.cloning` -- what is done to the mean network for the length of the cloning
  only (binary dropout's masks on the weights; nothing for the paper's methods).
- **Pruning**: ``prunes`` -- whether weights with log alpha > 3 are dropped before RL (Section IV-A). A variational
  network that does not prune is frozen for RL all the same (alphas fixed, no weight noise), with every weight of
  mu kept.
- **Network**: ``network_of`` -- the method whose pre-trained network (its checkpoint, start sigma included) this
  one starts RL from: None for its own. VD without pruning starts from VD's, so that pruning is all that differs.
- **Start sigma**: ``spread_from`` -- under the start sigma "spread" (sigma fitted to a dropout model's
  predictive spread), which method's mean network gives the spread: None for the method's own (it must be
  variational), otherwise the name of the method whose network pre-trained alike it follows (L2 follows VD's).
  A fixed sigma or "demos" needs nothing of the method.
- **Picture**: ``label`` and ``colour`` of its curves.

``pretrains`` is False for the two entries that are no pre-training: "none" (RL from a fresh network, sigma
fixed) and "expert" (the IK expert's reference line, scored but not trained: ``finetuned`` False).

A method with a number in its name: binary dropout takes its rate there, ``dropout@P`` (``dropout@0.5``), so that
every process that reads the shipped table knows it (spawned workers too) and its checkpoints and runs are named
by it. :func:`method` resolves such a name through the entry's :meth:`Method.resolved`.

Register a new method with :func:`register` (an instance of :class:`Method` or of a subclass overriding
:meth:`Method.penalty`); the experiments, the plots and ``--methods`` then know it by its name. A method
registered in a running Python is known to that process only: run its experiments with one worker.

Taught in chapter 05.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, replace

from torch import Tensor, nn

from vdtutorial.dropconnect import dropconnect
from vdtutorial.vd import model_kl, pruned_fraction

#: What separates a method's name from the number it takes (``dropout@0.5``).
PARAMETER_SEPARATOR = "@"


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
    """One row of the table: the module docstring, "these questions". The base class adds no penalty and no noise:
    a method that only changes the layers, the pruning or the network it starts from needs no subclass."""

    name: str
    label: str
    colour: str
    variational: bool = False
    prunes: bool = False
    spread_from: str | None = "vd"
    pretrains: bool = True
    finetuned: bool = True
    network_of: str | None = None

    def resolved(self, parameter: str | None) -> "Method":
        """The entry a name means: itself for the bare name (``parameter`` None); a method that takes a number in its
        name (``NAME@VALUE``) overrides this to return itself with that number."""
        if parameter is not None:
            raise ValueError(f"method {self.name!r} takes no {PARAMETER_SEPARATOR}parameter")
        return self

    def cloning(self, mu: nn.Module) -> AbstractContextManager:
        """A ``with`` block around the whole cloning, which may change how ``mu`` computes while it lasts (the
        optimiser holds mu's parameters, made before); by default nothing."""
        return nullcontext(mu)

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


@dataclass(frozen=True)
class BinaryDropout(WeightDecay):
    """Ordinary binary dropout on the weights of the mean network while it is cloned (:mod:`vdtutorial.dropconnect`:
    Bernoulli masks rescaled by 1 / (1 - p), absent at evaluation and in RL), plus the L2 baseline's penalty: the
    ablation with VD's multiplicative noise at one fixed ``rate`` p for every weight, without VD's learned per-weight
    variances and without pruning. The rate is part of the name (``dropout@P``, :meth:`resolved`), so the bare entry
    is a family, not a method that runs. Matched to VD, p is the mean of alpha / (1 + alpha) over the weights VD keeps
    (:func:`vdtutorial.analysis.dropout_rate.matched_dropout_rate`): the rate whose noise has VD's variance alpha.

    Its start sigma under "spread" follows VD's network, as L2's does: after cloning its network is plain, like L2's,
    and with the start sigma the same for both the two differ only in the cloning, which is the question."""

    rate: float | None = None

    def resolved(self, parameter: str | None) -> "BinaryDropout":
        if parameter is None:
            raise ValueError(
                f"method {self.name!r} takes its dropout rate in its name: {self.name}{PARAMETER_SEPARATOR}P "
                f"with 0 < P < 1 (e.g. {self.name}{PARAMETER_SEPARATOR}0.5)"
            )
        try:
            rate = float(parameter)
        except ValueError:
            rate = math.nan
        if not 0 < rate < 1:
            raise ValueError(
                f"method {self.name!r}: the rate after {PARAMETER_SEPARATOR} is a number in (0, 1), got {parameter!r}"
            )
        return replace(
            self, name=f"{self.name}{PARAMETER_SEPARATOR}{rate:g}", label=f"{self.label}, p={rate:g}", rate=rate
        )

    def cloning(self, mu: nn.Module) -> AbstractContextManager:
        if self.rate is None:
            raise ValueError(f"{self.name!r} has no rate: name it {self.name}{PARAMETER_SEPARATOR}P")
        return dropconnect(mu, self.rate)


#: The paper's two regularisers, no pre-training, the expert's reference line, and two ablations of VD: without its
#: pruning (VD's network, every weight kept) and binary dropout (VD's noise without its learned variances).
SHIPPED = (
    SparseVD("vd", "VD", "tab:blue", variational=True, prunes=True, spread_from=None),
    WeightDecay("l2", "L2", "tab:orange"),
    Method("none", "no pre-training", "tab:gray", spread_from=None, pretrains=False),
    Method("expert", "IK expert", "black", spread_from=None, pretrains=False, finetuned=False),
    SparseVD(
        "vd_unpruned",
        "VD without pruning",
        "tab:cyan",
        variational=True,
        prunes=False,
        spread_from=None,
        network_of="vd",
    ),
    BinaryDropout("dropout", "binary dropout", "tab:green"),
)
#: The table, by name, in the order of figures and legends: the shipped entries, then the registered ones.
METHODS: dict[str, Method] = {entry.name: entry for entry in SHIPPED}


def register(entry: Method) -> Method:
    """Add ``entry`` to the table, or replace an entry of the same name registered before (so that a notebook
    cell can be run again), and return it. The shipped entries cannot be replaced."""
    if entry.name in {shipped.name for shipped in SHIPPED} and entry not in SHIPPED:
        raise ValueError(f"{entry.name!r} is a shipped method: give yours another name")
    if PARAMETER_SEPARATOR in entry.name:
        raise ValueError(f"{entry.name!r}: a method's name has no {PARAMETER_SEPARATOR!r} (it introduces a number)")
    if entry.network_of is not None and entry.network_of not in METHODS:
        raise ValueError(f"{entry.name!r} starts from the network of {entry.network_of!r}, which is not in the table")
    if entry.spread_from is not None and entry.spread_from not in METHODS:
        raise ValueError(f"{entry.name!r} follows the spread of {entry.spread_from!r}, which is not in the table")
    METHODS[entry.name] = entry
    return entry


def method(name: str) -> Method:
    """The entry called ``name``, or for ``NAME@VALUE`` the entry ``NAME`` with that number
    (:meth:`Method.resolved`); ValueError naming the table's methods for another name."""
    family, separator, parameter = name.partition(PARAMETER_SEPARATOR)
    try:
        entry = METHODS[family]
    except KeyError:
        raise ValueError(f"no method {name!r}: the methods are {', '.join(METHODS)}") from None
    return entry.resolved(parameter if separator else None)


def is_shipped(name: str) -> bool:
    """Whether ``name`` is one of the shipped entries (with its number, for a method that takes one): a method every
    process knows, spawned workers included."""
    return name.partition(PARAMETER_SEPARATOR)[0] in {entry.name for entry in SHIPPED}


def pretraining_methods() -> tuple[str, ...]:
    """The names of the entries that pre-train, in the table's order."""
    return tuple(name for name, entry in METHODS.items() if entry.pretrains)


class _Labels(Mapping):
    """The table's labels by name, read at each look-up, so that a method registered later has its label too."""

    def __getitem__(self, name: str) -> str:
        if name in METHODS:  # a family's bare name too (``dropout``): its label without the number
            return METHODS[name].label
        try:
            return method(name).label
        except ValueError:
            raise KeyError(name) from None

    def __iter__(self) -> Iterator[str]:
        return iter(METHODS)

    def __len__(self) -> int:
        return len(METHODS)


#: Each method's label, by name (a live view of :data:`METHODS`).
METHOD_LABELS: Mapping[str, str] = _Labels()
