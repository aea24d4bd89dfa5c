"""Trusted checks of chapter 09's exercises: DART's noise (9.1) and DAgger's mixture (9.2).

Each round's learner is a small sparse-VD policy made from arrays the grader drew (:func:`.ch07.policy_from_arrays`),
handed over in train mode, where it samples its weights: a plan must act with its mean in eval mode. The data set
has random states and expert labels with an offset, so that the learner's errors have a mean and only their
uncentred mean outer product is DART's Sigma_hat. The kernel returns each plan's record and many actions of its
behaviour for one expert action; the grader recomputes the record with :func:`vdtutorial.beyond.dart.estimate_noise`
(the chapter's held-out split: ``cloning_config("vd")``, seed 0) or ``BETA ** k``, and tests the actions'
distribution to 6 standard errors: DART's noise N(0, Sigma), DAgger's share of expert actions, the learner's mean
action on the others.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import numpy as np
import torch

from vdtutorial.beyond.dagger import BETA
from vdtutorial.beyond.dart import estimate_noise, sigma_per_joint
from vdtutorial.beyond.imitation_rounds import cloning_config
from vdtutorial.course.checks import Check, Failures
from vdtutorial.course.checks.ch07 import policy_arrays, policy_from_arrays
from vdtutorial.demos import Demos
from vdtutorial.envs.scene import N_JOINTS
from vdtutorial.policy import GaussianPolicy

#: The chapter's hand-set start of DART, Sigma_0 = START_SIGMA^2 I (notebooks/09_beyond_the_paper.ipynb).
START_SIGMA = 0.05
#: Actions drawn from each DART behaviour (6 standard errors of a covariance entry stay under a tenth of the largest
#: variance) ...
DART_DRAWS = 10000
#: ... and from each DAgger behaviour (6 standard errors of the expert's share stay under 0.05).
DAGGER_DRAWS = 4000
#: States each behaviour is asked about in turn, and the range of their cups.
_STATES, _CUP_LOW, _CUP_HIGH = 4, (0.3, -0.3, 0.0), (0.6, 0.3, 0.0)


class _Learner(GaussianPolicy):
    """A round's learner. Its eval-mode mean action is remembered per state: a behaviour asks for it at thousands
    of steps over a few states, and the policy's forward pass would dominate the check's time."""

    def act(self, obs, deterministic=False):
        if self.training or not deterministic or isinstance(obs, dict):
            return super().act(obs, deterministic)
        memo = self.__dict__.setdefault("_means", {})
        key = np.asarray(obs, dtype=np.float32)
        key = (key.shape, key.tobytes())
        if key not in memo:
            memo[key] = super().act(obs, deterministic=True)
        return memo[key].copy()


def _demos_arrays(rng: np.random.Generator) -> dict:
    """A data set of 20 episodes of 3 to 12 steps: random joints and cups, labels with a random offset."""
    lengths = rng.integers(3, 13, 20)
    n = int(lengths.sum())
    return {
        "joints": rng.uniform(-np.pi, np.pi, (n, N_JOINTS)),
        "cup": rng.uniform(_CUP_LOW, _CUP_HIGH, (n, 3)),
        "actions": rng.normal(0, 0.3, (n, N_JOINTS)) + rng.normal(0, 0.3, N_JOINTS),
        "episode": np.repeat(np.arange(20), lengths),
        "t": np.concatenate([np.arange(k) for k in lengths]),
    }


def _demos(arrays: dict) -> Demos:
    return Demos(
        **{
            key: np.asarray(arrays[key], dtype=np.int64 if key in ("episode", "t") else np.float32)
            for key in ("joints", "cup", "actions", "episode", "t")
        }
    )


def _round(rng: np.random.Generator, k: int, learner: bool) -> dict:
    """Round ``k``'s inputs: a learner and its data set (or none), states and an expert action to act on."""
    case = {
        "k": k,
        "learner": learner,
        "draw_seed": int(rng.integers(2**31)),
        "states": np.column_stack(
            [rng.uniform(-np.pi, np.pi, (_STATES, N_JOINTS)), rng.uniform(_CUP_LOW, _CUP_HIGH, (_STATES, 3))]
        ),
        "expert_action": rng.uniform(5, 9, N_JOINTS) * rng.choice([-1, 1], N_JOINTS),
    }
    if learner:
        case.update(params=policy_arrays(rng), demos=_demos_arrays(rng))
    return case


def _plan_and_draws(plan, case: dict, draws: int) -> dict:
    """Call ``plan`` on a round's inputs (the learner in train mode) and draw ``draws`` actions of its behaviour."""
    learner = bool(case["learner"])
    policy = policy_from_arrays(case["params"], _Learner) if learner else None
    behaviour, record = plan(int(case["k"]), policy, _demos(case["demos"]) if learner else None)
    rng, states = np.random.default_rng(int(case["draw_seed"])), case["states"].astype(np.float32)
    actions = [behaviour(states[i % len(states)], case["expert_action"].copy(), rng) for i in range(draws)]
    return {"record": record, "actions": np.array(actions, dtype=np.float64)}


def dart_inputs(rng: np.random.Generator) -> dict:
    """Round 0 (no learner), round 1 and a random later round, each with its own learner and data set."""
    return {
        "round0": _round(rng, 0, False),
        "round1": _round(rng, 1, True),
        "roundk": _round(rng, int(rng.integers(2, 6)), True),
    }


def dart_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        got = _plan_and_draws(namespace["dart_plan"], inputs[key], DART_DRAWS)
        out[key] = {
            "covariance": np.asarray(got["record"]["covariance"], dtype=np.float64),
            "sigma_per_joint": np.asarray(got["record"]["sigma_per_joint"], dtype=np.float64),
            "actions": got["actions"],
        }
    return out


def _noise_matches(actions: np.ndarray, centre: np.ndarray, covariance: np.ndarray) -> bool:
    """Whether ``actions`` look like ``centre`` + N(0, covariance): their mean and uncentred covariance around
    ``centre`` within 6 standard errors, entry by entry."""
    noise, n = actions - centre, len(actions)
    variance = np.diag(covariance)
    mean_ok = np.abs(noise.mean(0)) <= 6 * np.sqrt(variance / n) + 1e-12
    spread = np.sqrt((np.outer(variance, variance) + covariance**2) / n)
    return bool(np.all(mean_ok) and np.all(np.abs(noise.T @ noise / n - covariance) <= 6 * spread + 1e-12))


def dart_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"round {int(inputs[key]['k'])}"
        if bool(case["learner"]):
            covariance = estimate_noise(
                policy_from_arrays(case["params"]), _demos(case["demos"]), cloning_config("vd"), seed=0
            )
            what = "Sigma_hat: the mean outer product of the eval-mode errors on the held-out states"
        else:
            covariance, what = START_SIGMA**2 * np.eye(N_JOINTS), "round 0: Sigma_0 = START_SIGMA^2 I"
        failures.close(got["covariance"], covariance, f"{where}: {what}", 1e-4, 1e-10)
        failures.close(
            got["sigma_per_joint"],
            sigma_per_joint(covariance),
            f"{where}: sigma per joint, the standard deviation of each joint's noise",
            1e-4,
            1e-10,
        )
        actions = np.asarray(got["actions"], dtype=float)
        if failures.true(actions.shape == (DART_DRAWS, N_JOINTS), f"{where}: the behaviour returns one action"):
            failures.true(
                _noise_matches(actions, case["expert_action"], covariance),
                f"{where}: the executed action must be the expert's plus N(0, Sigma)",
            )
    return failures


def dagger_inputs(rng: np.random.Generator) -> dict:
    """Round 0 without and with a learner (the expert alone), then two random rounds 1 to 4 with learners."""
    return {
        "round0": _round(rng, 0, False),
        "round0_learner": _round(rng, 0, True),
        "roundk": _round(rng, int(rng.integers(1, 3)), True),
        "roundk_later": _round(rng, int(rng.integers(3, 5)), True),
    }


def dagger_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        got = _plan_and_draws(namespace["dagger_plan"], inputs[key], DAGGER_DRAWS)
        out[key] = {"beta": float(got["record"]["beta"]), "actions": got["actions"]}
    return out


def dagger_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"round {int(inputs[key]['k'])}"
        where += " with a learner" if bool(case["learner"]) else " without a learner"
        beta = BETA ** int(case["k"])
        failures.close(got["beta"], beta, f"{where}: beta_k = BETA ** k", 0, 1e-12)
        actions = np.asarray(got["actions"], dtype=float)
        if not failures.true(actions.shape == (DAGGER_DRAWS, N_JOINTS), f"{where}: the behaviour returns one action"):
            continue
        expert = np.all(np.isclose(actions, case["expert_action"]), axis=1)
        share_ok = abs(expert.mean() - beta) <= 6 * np.sqrt(beta * (1 - beta) / DAGGER_DRAWS) + 1e-12
        failures.true(share_ok, f"{where}: the expert must act in a share beta_k of the steps")
        if bool(case["learner"]) and not expert.all():
            policy = policy_from_arrays(case["params"]).eval()
            with torch.no_grad():
                mean = policy.act(case["states"].astype(np.float32), deterministic=True)
            learner = mean[np.arange(DAGGER_DRAWS) % _STATES]
            failures.true(
                np.allclose(actions[~expert], learner[~expert], rtol=0, atol=1e-5),
                f"{where}: when the expert does not act, the learner's mean action (eval mode) on the state",
            )
    return failures


CHECKS = [
    Check("ch09_dart_noise", dart_inputs, dart_probe, dart_verdict),
    Check("ch09_dagger_plan", dagger_inputs, dagger_probe, dagger_verdict),
]
