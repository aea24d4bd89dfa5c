"""Trusted checks of chapter 03's exercises: one noisy rollout (3.1) and the data set D (3.2).

3.1: the kernel runs the student's ``noisy_rollout`` in a reaching env of its own, with a generator seeded as
:func:`vdtutorial.demos.generate_demos` seeds its own (one draw for the reset seed, then the noise). The grader
compares the trajectory with the first one of ``generate_demos``'s rollout loop (:func:`vdtutorial.demos.collect`) for
that seed and Sigma, and labels each returned state again with its own :class:`~vdtutorial.expert.IKExpert`.

3.2: the student's ``rollout_demos`` runs with a stand-in for ``noisy_rollout`` (so that 3.2 does not depend on 3.1):
it resets the env with the seed it gets, draws from the generator it gets the noise a rollout of that length would
draw, and returns a trajectory the grader chose. Two cases have random trajectories, whose data set the grader puts
together itself (the last trajectory cut at ``samples``, or ``samples`` ending where a trajectory ends); in the third
the trajectories are ``generate_demos``'s own, and the data set must be ``generate_demos``'s.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

from functools import lru_cache

import gymnasium as gym
import numpy as np

from vdtutorial.course.checks import Check, Failures, swapped
from vdtutorial.demos import ARRAYS, Demos, collect, generate_demos
from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.base import HORIZON, MAX_DELTA
from vdtutorial.envs.scene import HOME
from vdtutorial.expert import IKExpert

#: The largest reset seed (exclusive) that generate_demos draws, as chapter 03's exercises draw it too.
SEED_BOUND = 2**31 - 1


@lru_cache(maxsize=None)
def _reach(role: str):
    """A reaching env (state observations) and its expert, built once per process and role: the probe's in the
    kernel, the verdict's in the grader (a notebook checking itself has both, so that neither moves the other's)."""
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    return env, IKExpert(env)


def _reset_seed(seed: int) -> tuple[np.random.Generator, int]:
    """The generator of ``generate_demos(seed=seed)`` after its first draw, and that draw (its first reset seed)."""
    rng = np.random.default_rng(seed)
    return rng, int(rng.integers(SEED_BOUND))


def rollout_inputs(rng: np.random.Generator) -> dict:
    """Three trajectories: one without noise, two at a random Sigma of the chapter's range."""
    sigmas = (0.0, rng.uniform(0.05, 0.5), rng.uniform(0.05, 0.5))
    return {f"case{k}": {"sigma": sigma, "seed": int(rng.integers(SEED_BOUND))} for k, sigma in enumerate(sigmas)}


def rollout_probe(namespace: dict, inputs: dict) -> dict:
    env, expert = _reach("probe")
    out = {}
    for key in sorted(inputs):
        rng, reset_seed = _reset_seed(int(inputs[key]["seed"]))
        joints, labels = namespace["noisy_rollout"](env, expert, rng, float(inputs[key]["sigma"]), seed=reset_seed)
        out[key] = {"joints": joints, "labels": labels}
    return out


def rollout_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    env, expert = _reach("verdict")
    for key in sorted(inputs):
        where, sigma, seed = f"trajectory {key[-1]}", float(inputs[key]["sigma"]), int(inputs[key]["seed"])
        joints = np.asarray(outputs[key]["joints"], dtype=float)
        labels = np.asarray(outputs[key]["labels"], dtype=float)
        if not failures.true(
            joints.ndim == 2 and joints.shape == labels.shape and joints.shape[1] == 6 and 1 <= len(joints) <= HORIZON,
            f"{where}: return two arrays with one row of six joint values per visited state, at most HORIZON rows",
        ):
            continue
        failures.close(joints[0], HOME, f"{where}: the first state is the home pose", 0, 1e-6)
        env.reset(seed=_reset_seed(seed)[1])
        expert.reset()
        failures.close(
            labels,
            [expert.action(q) for q in joints],
            f"{where}: labels must be the noiseless expert action in each visited state",
            0,
            1e-6,
        )
        moves = np.diff(joints, axis=0)
        if sigma == 0:
            failures.close(
                moves, labels[:-1], f"{where}: without noise the arm must execute the expert's action", 0, 1e-6
            )
        elif len(joints) > 1:
            failures.true(not np.allclose(moves, labels[:-1]), f"{where}: the executed actions must carry the noise")
        # generate_demos's rollout for T states: its first trajectory, which must have ended there
        library, record = collect(
            "reach", len(joints), seed, lambda state, label, rng: label + rng.normal(0.0, sigma, 6)
        )
        failures.true(
            record["episodes"] == record["finished"] == 1 and np.allclose(joints, library.joints, rtol=0, atol=1e-5),
            f"{where}: the visited states differ from the library's rollout (execute the label plus noise "
            "drawn from rng, one draw per step; stop when the episode ends)",
        )
    return failures


def _trajectories(rng, lengths) -> dict:
    """Random trajectories of the given lengths, as arrays padded to the longest (what a stand-in returns)."""
    longest = int(max(lengths))
    shape = (len(lengths), longest, 6)
    return {
        "lengths": np.asarray(lengths, dtype=int),
        "joints": rng.uniform(-np.pi, np.pi, shape),
        "labels": rng.uniform(-MAX_DELTA, MAX_DELTA, shape),
    }


def demos_inputs(rng: np.random.Generator) -> dict:
    """Random trajectories with ``samples`` ending inside one (case 0) or where one ends (case 1); and the
    trajectories of ``generate_demos`` (case 2), its last one lengthened by random states that must be cut off."""
    lengths = rng.integers(2, 7, size=5)
    whole = int(rng.integers(2, 4))
    case0 = {"samples": int(lengths[:whole].sum() + rng.integers(1, lengths[whole])), **_trajectories(rng, lengths)}
    lengths = rng.integers(1, 7, size=4)
    case1 = {"samples": int(lengths[: int(rng.integers(1, 3))].sum()), **_trajectories(rng, lengths)}
    samples, sigma, seed = int(rng.integers(6, 15)), rng.uniform(0.1, 0.5), int(rng.integers(1000))
    library = generate_demos("reach", samples, sigma, seed, progress=False)
    lengths = np.bincount(library.episode)
    longer = lengths.copy()
    longer[-1] += rng.integers(1, 4)
    case2 = {"samples": samples, **_trajectories(rng, longer)}
    for name, column in (("joints", library.joints), ("labels", library.actions)):
        for e, length in enumerate(lengths):
            case2[name][e, :length] = column[library.episode == e]
    cases = {"case0": case0, "case1": case1, "case2": case2}
    for k in (0, 1):
        cases[f"case{k}"].update(sigma=rng.uniform(0.05, 0.5), seed=int(rng.integers(1000)))
    case2.update(sigma=sigma, seed=seed)
    return cases


def _stand_in(case: dict, calls: list):
    """noisy_rollout's stand-in for one case: records each call, then resets, draws and returns as described above."""

    def rollout(env, expert, rng, sigma, seed):
        calls.append((int(seed), float(sigma), env, expert))
        k = (len(calls) - 1) % len(case["lengths"])
        env.reset(seed=seed)
        length = int(case["lengths"][k])
        for _ in range(length):
            rng.normal(0.0, sigma, 6)  # the noise a rollout of this length draws
        return case["joints"][k, :length].copy(), case["labels"][k, :length].copy()

    return rollout


def demos_probe(namespace: dict, inputs: dict) -> dict:
    env, expert = _reach("probe")
    out = {}
    for key in sorted(inputs):
        case, calls = inputs[key], []
        with swapped(namespace, env=env, expert=expert, noisy_rollout=_stand_in(case, calls)):
            demos = namespace["rollout_demos"](float(case["sigma"]), int(case["samples"]), seed=int(case["seed"]))
        got = {
            "is_demos": isinstance(demos, Demos),
            "seeds": [c[0] for c in calls],
            "sigmas": [c[1] for c in calls],
            "context": [c[2] is env and c[3] is expert for c in calls],
        }
        if got["is_demos"]:
            got.update(rows=len(demos), **{name: np.asarray(getattr(demos, name), dtype=float) for name in ARRAYS})
        out[key] = got
    return out


def _expected(case: dict, env) -> tuple[list[int], dict]:
    """The reset seeds a right rollout_demos passes on, and the data set it makes, from a case's trajectories."""
    rng, samples = np.random.default_rng(int(case["seed"])), int(case["samples"])
    seeds, rows, n = [], {name: [] for name in ARRAYS}, 0
    for k, length in enumerate(case["lengths"]):
        if n >= samples:
            break
        seeds.append(int(rng.integers(SEED_BOUND)))
        rng.normal(0.0, float(case["sigma"]), (int(length), 6))
        keep = min(int(length), samples - n)
        env.reset(seed=seeds[-1])
        columns = {
            "joints": case["joints"][k, :keep],
            "cup": np.tile(env.unwrapped.cup_position, (keep, 1)),
            "actions": case["labels"][k, :keep],
            "episode": np.full(keep, k),
            "t": np.arange(keep),
        }
        for name in ARRAYS:
            rows[name].append(columns[name])
        n += keep
    return seeds, {name: np.concatenate(parts) for name, parts in rows.items()}


def demos_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    env = _reach("verdict")[0]
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"case {key[-1]}"
        seeds, want = _expected(case, env)
        if key == "case2":  # the library's trajectories: the library's data set
            library = generate_demos(
                "reach", int(case["samples"]), float(case["sigma"]), int(case["seed"]), progress=False
            )
            want = {name: getattr(library, name) for name in ARRAYS}
        failures.equal(
            got["seeds"],
            seeds,
            f"{where}: call noisy_rollout once per trajectory until D is full, with "
            "reset seeds drawn from the generator seeded with `seed`, and pass that generator on",
        )
        failures.true(
            np.allclose(got["sigmas"], float(case["sigma"]), rtol=0, atol=1e-12),
            f"{where}: pass Sigma on to noisy_rollout",
        )
        failures.true(got["context"], f"{where}: pass the chapter's env and expert to noisy_rollout")
        if not failures.true(
            got["is_demos"] and int(got["rows"]) == int(case["samples"]),
            f"{where}: return a Demos with exactly `samples` rows",
        ):
            continue
        for name, what in (
            ("joints", "the joint angles of the visited states"),
            ("cup", "each row's cup position"),
            ("actions", "the actions (the trajectories' labels)"),
            ("episode", "the episode indices"),
            ("t", "the time steps within each trajectory"),
        ):
            failures.close(got[name], want[name], f"{where}: {what}", 0, 1e-6)
    return failures


CHECKS = [
    Check("ch03_noisy_rollout", rollout_inputs, rollout_probe, rollout_verdict),
    Check("ch03_rollout_demos", demos_inputs, demos_probe, demos_verdict),
]
