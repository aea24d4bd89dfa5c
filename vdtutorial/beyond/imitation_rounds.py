"""Rounds of "collect -> aggregate -> re-train": the loop that DART and DAgger share.

Both methods improve on one-shot behavioural cloning the same way: collect expert-labelled states with
some behaviour, add them to everything collected so far, clone the expert again on the whole set, and let
the new policy decide how the next round behaves. They differ only in that behaviour: DART
(:mod:`vdtutorial.beyond.dart`) runs the expert with noise fitted to the last policy's errors, DAgger
(:mod:`vdtutorial.beyond.dagger`) runs a mixture of the expert and the last policy. This module holds the loop,
with the behaviour left to the caller, so the two methods are measured with exactly the same rollout,
labelling (:func:`vdtutorial.demos.collect`), aggregation and pre-training (:func:`vdtutorial.pretrain.pretrain`).

Labels are the budget. The expert labels every state it is shown (one query per state), and the
experiments compare methods at an equal number of labels, so ``samples`` is split over the rounds in
fixed shares decided before the first round (:func:`round_sizes`) and every round's queries and the wall
time spent in the expert are recorded.
Taught in chapter 09.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from vdtutorial.demos import ARRAYS, FORMAT_VERSION, Demos, collect, success_rate
from vdtutorial.policy import GaussianPolicy
from vdtutorial.pretrain import PAPER_SIGMA_OPTION, PretrainConfig, pretrain


def concatenate_demos(parts: list[Demos], meta: dict) -> Demos:
    """One data set from several collected one after another (the rounds), with episode numbers shifted so
    that episodes of different parts stay distinct: the held-out split holds out whole episodes."""
    offsets = np.cumsum([0] + [int(part.episode.max()) + 1 if len(part) else 0 for part in parts[:-1]])
    arrays = {name: np.concatenate([getattr(part, name) for part in parts]) for name in ARRAYS}
    arrays["episode"] = np.concatenate([part.episode + offset for part, offset in zip(parts, offsets)]).astype(np.int32)
    return Demos(meta=dict(meta), **arrays)


@dataclass
class RoundsResult:
    """What the rounds produced: ``demos`` the aggregated data set, ``policy`` cloned on it (eval mode,
    not pruned), ``parts`` each round's own data, ``rounds`` one record per round (what the behaviour
    was, labels, expert time, the policy's held-out error)."""

    demos: Demos
    policy: GaussianPolicy
    parts: list[Demos]
    rounds: list[dict]

    @property
    def expert_queries(self) -> int:
        return sum(r["expert_queries"] for r in self.rounds)

    @property
    def expert_seconds(self) -> float:
        return sum(r["expert_seconds"] for r in self.rounds)


def round_sizes(samples: int, rounds: int) -> list[int]:
    """Labels per round: ``samples`` split as evenly as possible (earlier rounds take the remainder)."""
    if rounds < 1 or samples < rounds:
        raise ValueError(f"need rounds >= 1 and at least one label per round, got samples={samples}, rounds={rounds}")
    return [len(part) for part in np.array_split(np.arange(samples), rounds)]


def round_seed(seed: int, k: int) -> int:
    """Seed of round ``k``'s rollouts: derived from (seed, k), so rounds draw different cups."""
    return int(np.random.SeedSequence([seed, k]).generate_state(1)[0])


def cloning_config(reg: str, config: PretrainConfig | None = None) -> PretrainConfig:
    """The pre-training settings of every round: ``config`` (default ``PretrainConfig()``, the experiments' state
    settings) for ``reg`` with sigma left at the paper's fixed value (the rounds need only the mean action; the
    start sigma of RL is set later)."""
    return replace(config or PretrainConfig(), reg=reg, initial_sigma=PAPER_SIGMA_OPTION)


def run_rounds(
    method: str,
    task: str,
    reg: str,
    samples: int,
    rounds: int,
    seed: int,
    plan,
    config: PretrainConfig | None = None,
    progress: bool = False,
) -> RoundsResult:
    """``rounds`` rounds of collect -> aggregate -> re-train with the method ``reg`` (:mod:`vdtutorial.methods`).

    ``plan(k, policy, demos)`` is called at the start of round ``k`` with the policy of the round before
    and the data aggregated so far (both None in round 0) and returns ``(behaviour, record)``: the
    behaviour of :func:`vdtutorial.demos.collect` for this round, and what to record about it. The
    policy of every round is cloned afresh (seed ``seed``) on all the data so far."""
    cfg = cloning_config(reg, config)
    policy, demos, parts, records = None, None, [], []
    for k, size in enumerate(round_sizes(samples, rounds)):
        behaviour, record = plan(k, policy, demos)
        part, rollout = collect(task, size, round_seed(seed, k), behaviour, progress, f"{method} round {k}")
        parts.append(part)
        meta = {
            "format_version": FORMAT_VERSION,
            "task": task,
            "samples": sum(map(len, parts)),
            "seed": int(seed),
            "method": method,
            "reg": reg,
            "rounds_done": k + 1,
        }
        demos = concatenate_demos(parts, meta)
        start = time.perf_counter()
        policy, history = pretrain(demos, cfg, seed=seed, progress=progress)
        records.append(
            {
                "round": k,
                **record,
                "labels": size,
                "labels_total": len(demos),
                "expert_queries": rollout["expert_queries"],
                "expert_seconds": rollout["expert_seconds"],
                "episodes": rollout["episodes"],
                "rollout_success_rate": success_rate(rollout),
                "pretrain_seconds": time.perf_counter() - start,
                "val_mse": history[-1]["val_mse"],
            }
        )
    return RoundsResult(demos, policy, parts, records)
