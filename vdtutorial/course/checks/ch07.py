"""Trusted checks of chapter 07's exercises: pruning a VD policy for RL (7.1) and steps to a level (7.2).

7.1: small sparse-VD policies are made from weights and log sigma^2 the grader drew; the kernel returns the
student's pruned copy (its state, which parameters train, its forward passes) and the original after the call, and
the grader prunes its own copy with :meth:`vdtutorial.policy.GaussianPolicy.prune_`. 7.2: random learning-curve rows
of three methods over a few seeds, shuffled; the grader's levels are read off the library's smoothed curves
(:func:`vdtutorial.experiments.curves_from_rows`, :func:`vdtutorial.experiments.steps_to_reach`), exact ties
included where the smoothing is exact (a window of one iteration).

:func:`policy_arrays` and :func:`policy_from_arrays` also serve chapter 09's checks.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from vdtutorial.course.checks import Check, Failures
from vdtutorial.experiments import curves_from_rows, steps_to_reach
from vdtutorial.policy import GaussianPolicy
from vdtutorial.vd import THRESHOLD, svdo_layers

#: A small state-mode policy (6 joints and the cup: 9 numbers in, 6 joint changes out) with sparse VD layers.
POLICY_CONFIG = dict(
    kind="state", obs_shape=(9,), action_dim=6, variational=True, sizes={"scene_hidden": (8, 6), "joint_hidden": (8,)}
)
#: The methods of 7.2's rows, with labels of their own (the library's curves go by label, the exercise by method).
_METHODS = {"vd": "VD pre-trained", "none": "no pre-training", "l2": "L2 pre-trained"}


@functools.lru_cache(maxsize=1)
def _parameter_shapes() -> tuple:
    return tuple((name, tuple(p.shape)) for name, p in GaussianPolicy(**POLICY_CONFIG).named_parameters())


def policy_arrays(rng: np.random.Generator) -> dict:
    """Random parameters of a :data:`POLICY_CONFIG` policy: log alpha on both sides of any threshold in [-2, 6]."""
    arrays = {}
    for name, shape in _parameter_shapes():
        arrays[name] = rng.normal(-6, 6, shape) if name.endswith("log_sigma2") else rng.normal(0, 0.5, shape)
    return arrays


def policy_from_arrays(arrays: dict, kind: type = GaussianPolicy) -> GaussianPolicy:
    """A :data:`POLICY_CONFIG` policy of class ``kind`` holding ``arrays`` (unpruned, in train mode)."""
    policy = kind(**POLICY_CONFIG)
    with torch.no_grad():
        for name, parameter in policy.named_parameters():
            parameter.copy_(torch.as_tensor(np.asarray(arrays[name]), dtype=torch.float32))
    return policy.train()


def prune_inputs(rng: np.random.Generator) -> dict:
    """Three policies: one pruned at the default threshold (no argument), two at random thresholds."""
    cases = {}
    for k in range(3):
        cases[f"case{k}"] = {
            "params": policy_arrays(rng),
            "default": k == 0,
            "threshold": THRESHOLD if k == 0 else float(rng.uniform(-2, 6)),
            "x": np.concatenate([rng.uniform(-3, 3, (12, 6)), rng.uniform(-0.5, 0.8, (12, 3))], 1),
        }
    return cases


def prune_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        policy = policy_from_arrays(case["params"])
        prune_for_rl = namespace["prune_for_rl"]
        mine = prune_for_rl(policy) if bool(case["default"]) else prune_for_rl(policy, float(case["threshold"]))
        x = torch.as_tensor(case["x"], dtype=torch.float32)
        got = {
            "copy": mine is not policy,
            "original": policy.state_dict(),
            "original_trains": {name: p.requires_grad for name, p in policy.named_parameters()},
            "state": mine.state_dict(),
            "trains": {name: p.requires_grad for name, p in mine.named_parameters()},
            "layers": len(svdo_layers(mine)),
        }
        mine.train()
        with torch.no_grad():
            dist = mine.distribution(x)
            got.update(mean=dist.mean, std=dist.stddev, mu_once=mine.mu(x), mu_again=mine.mu(x))
        out[key] = got
    return out


def _same(got: dict, want: dict) -> bool:
    return set(got) == set(want) and all(np.array_equal(np.asarray(got[k]), np.asarray(want[k])) for k in want)


def prune_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"policy {key[-1]}"
        ref = policy_from_arrays(case["params"])
        original = {name: value.numpy().copy() for name, value in ref.state_dict().items()}
        original_trains = {name: p.requires_grad for name, p in ref.named_parameters()}
        ref.prune_(float(case["threshold"]))
        failures.true(got["copy"], f"{where}: prune a copy, not the policy you were given")
        failures.true(
            _same(got["original"], original) and _same(got["original_trains"], original_trains),
            f"{where}: the policy you were given must stay unchanged (unpruned)",
        )
        state = {name: value.numpy() for name, value in ref.state_dict().items()}
        if not failures.true(
            int(got["layers"]) == len(svdo_layers(ref)) and set(got["state"]) == set(state),
            f"{where}: return a copy of the policy, with all of its layers",
        ):
            continue
        layers = [name.rsplit(".", 1)[0] for name in state if name.endswith(".pruned")]
        for part, what in (
            ("pruned", "set every layer's `pruned` flag"),
            ("mask", "`mask` must keep exactly the weights with log alpha <= threshold"),
            ("weight", "pruned weights exactly 0, kept weights unchanged"),
            ("bias", "biases unchanged"),
            ("log_sigma2", "log sigma^2 unchanged"),
        ):
            failures.true(
                all(np.array_equal(got["state"][f"{layer}.{part}"], state[f"{layer}.{part}"]) for layer in layers),
                f"{where}: {what}",
            )
        trains = {name: p.requires_grad for name, p in ref.named_parameters()}
        failures.true(
            all(not got["trains"][n] for n in trains if n.endswith("log_sigma2")),
            f"{where}: alpha (log_sigma2) must not train during RL",
        )
        failures.true(
            all(got["trains"][n] for n in trains if not n.endswith("log_sigma2")),
            f"{where}: the weights and biases must still train",
        )
        x = torch.as_tensor(case["x"], dtype=torch.float32)
        with torch.no_grad():
            dist = ref.distribution(x)
            failures.close(got["mean"], dist.mean, f"{where}: the pruned policy's mean action", 1e-5, 1e-6)
            failures.close(got["std"], dist.stddev, f"{where}: the pruned policy's sigma", 1e-5, 1e-6)
        failures.true(
            np.array_equal(got["mu_once"], got["mu_again"]), f"{where}: deterministic forward pass, also in train mode"
        )
    return failures


def _curve_rows(rng: np.random.Generator, seeds: int, iterations: int) -> dict:
    """Rows of three methods (``method``, ``label``, ``seed``, ``iteration``, ``env_steps``, ``successes``),
    shuffled; uneven env steps per iteration, seeds not numbered from 0."""
    env_steps = np.cumsum(rng.integers(100, 1000, iterations))
    seed_ids = rng.choice(100, seeds, replace=False)
    rows = [
        (method, label, s, i, env_steps[i], rng.poisson(1 + slope * i / iterations))
        for (method, label), slope in zip(_METHODS.items(), rng.uniform(0, 9, 3))
        for s in seed_ids
        for i in range(iterations)
    ]
    rows = [rows[j] for j in rng.permutation(len(rows))]
    columns = ("method", "label", "seed", "iteration", "env_steps", "successes")
    return {name: np.array([row[c] for row in rows]) for c, name in enumerate(columns)}


def _as_rows(rows: dict) -> list[dict]:
    """The rows as the chapter's dicts of plain Python values."""
    return [
        {
            "method": str(m),
            "label": str(lab),
            "seed": int(s),
            "iteration": int(i),
            "env_steps": int(e),
            "successes": int(v),
        }
        for m, lab, s, i, e, v in zip(
            *(rows[c] for c in ("method", "label", "seed", "iteration", "env_steps", "successes"))
        )
    ]


def steps_inputs(rng: np.random.Generator) -> dict:
    """Four sets of rows with windows of 1, 1 and two random ones; per method, four levels reached at random points,
    one never reached and (window 1) one equal to the curve's highest value."""
    cases = {}
    for k, window in enumerate((1, 1, None, None)):
        seeds, iterations = int(rng.integers(1, 6)), int(rng.integers(10, 61))
        window = window or int(rng.integers(2, iterations + 1))
        rows = _curve_rows(rng, seeds, iterations)
        curves = curves_from_rows(_as_rows(rows), "successes", window)
        methods, levels = [], []
        for method, label in _METHODS.items():
            top = float(curves[label].mean.max())
            chosen = [float(v) for v in rng.uniform(0.2, 1.0, 4) * top] + [top + 1] + ([top] if window == 1 else [])
            methods += [method] * len(chosen)
            levels += chosen
        cases[f"case{k}"] = {"rows": rows, "window": window, "methods": np.array(methods), "levels": np.array(levels)}
    return cases


def steps_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        rows = _as_rows(case["rows"])
        found = [
            namespace["steps_to_level"](rows, str(m), float(level), int(case["window"]))
            for m, level in zip(case["methods"], case["levels"])
        ]
        out[key] = {"never": [f is None for f in found], "steps": [math.nan if f is None else float(f) for f in found]}
    return out


def steps_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"rows {key[-1]}"
        curves = curves_from_rows(_as_rows(case["rows"]), "successes", int(case["window"]))
        want = [
            steps_to_reach(curves[_METHODS[str(m)]].steps, curves[_METHODS[str(m)]].mean, float(level))
            for m, level in zip(case["methods"], case["levels"])
        ]
        never, steps = np.asarray(got["never"]), np.asarray(got["steps"], dtype=float)
        if not failures.true(never.shape == steps.shape == (len(want),), f"{where}: one answer per question"):
            continue
        wrong_never = [q for q, (w, n) in enumerate(zip(want, never)) if w is None and not n]
        wrong_steps = [q for q, (w, n, s) in enumerate(zip(want, never, steps)) if w is not None and (n or s != w)]
        if wrong_never:
            failures.append(f"{where}, question {wrong_never[0]}: a level the smoothed curve never reaches gives None")
        if wrong_steps:
            failures.append(
                f"{where}, question {wrong_steps[0]}: the env steps of the first point where the smoothed "
                "mean over seeds is at or above the level"
            )
    return failures


CHECKS = [
    Check("ch07_prune", prune_inputs, prune_probe, prune_verdict),
    Check("ch07_steps_to_level", steps_inputs, steps_probe, steps_verdict),
]
