"""DAgger for the IK expert: label the states the learner itself visits.

Behavioural cloning trains on the expert's states and is then run on its own, where its small errors take
it to states the expert never showed it (covariate shift). DAgger (Ross, Gordon, Bagnell, "A Reduction of
Imitation Learning and Structured Prediction to No-Regret Online Learning", AISTATS 2011; the paper's ref.
[21]) goes to those states: in round i it runs the mixture

    pi_i = beta_i pi_exp + (1 - beta_i) pi_hat_i          (their Algorithm 3.1)

asks the expert for its action in every visited state, adds these pairs to the data set D <- D u D_i, and
trains pi_hat_{i+1} on the whole of D.

**Choices made here.** The mixture is taken per step: with probability beta_i the executed action is the
expert's, otherwise the learner's mean action (eval mode, so a sparse-VD policy acts with its pruned
weights). beta_i = beta^i with beta = 0.5 (Ross et al.'s decaying schedule beta_i = p^(i-1), counted from
round 0): round 0 has beta_0 = 1, i.e. behavioural cloning on noise-free expert demonstrations, and later
rounds hand more and more of the steps to the learner. The data of every round keeps its expert labels
(eq. 8: the label is pi_exp(s), whoever acted), and each round clones afresh on all the data so far
(:mod:`vdtutorial.beyond.imitation_rounds`).

**Cost.** Every visited state is one expert query; the loop also records the wall time spent in the expert
(building G per episode, eq. 10 per state) and in the re-training of every round: the paper calls DAgger
"computationally quite expensive" against demonstrations generated once, and these are the numbers that
claim is about.
Taught in chapter 09.
"""

from __future__ import annotations

from vdtutorial.beyond.imitation_rounds import RoundsResult, run_rounds
from vdtutorial.pretrain import PretrainConfig

#: beta of the schedule beta_i = BETA^i.
BETA = 0.5


def mixture(policy, beta: float):
    """The behaviour of a DAgger round: per step the expert's action with probability ``beta``, else the
    learner's mean action on the state (the expert alone when there is no learner yet)."""
    if policy is None or beta >= 1:
        return lambda state, a_exp, rng: a_exp
    policy.eval()
    return lambda state, a_exp, rng: a_exp if rng.random() < beta else policy.act(state, deterministic=True)


def dagger(
    task: str = "reach",
    reg: str = "vd",
    samples: int = 8000,
    rounds: int = 4,
    beta: float = BETA,
    seed: int = 0,
    config: PretrainConfig | None = None,
    progress: bool = False,
) -> RoundsResult:
    """DAgger's rounds (module docstring, "Choices made here") with beta_i = ``beta``^i, cloning with ``reg``;
    ``samples``
    expert labels in all, split evenly over the rounds."""
    if not 0 <= beta <= 1:
        raise ValueError(f"beta must be in [0, 1], got {beta!r}")

    def plan(k, policy, demos):
        return mixture(policy, beta**k), {"beta": beta**k}

    return run_rounds("dagger", task, reg, samples, rounds, seed, plan, config, progress)
