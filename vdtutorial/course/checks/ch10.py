"""Trusted checks of chapter 10's exercises: Welch's interval and verdict (10.1) and Holm's procedure (10.2).

10.1: random per-seed levels of two methods (3 to 12 seeds each, unequal spreads), both directions of the claim,
the default confidence and random ones, and three small fixed cases that give each verdict; the grader recomputes
them with :func:`vdtutorial.experiments.effects.welch_interval` and :func:`vdtutorial.experiments.effects.verdict`.
10.2: random families of 0 to 9 p-values near the thresholds, some NaN, at the default alpha and random ones; the
grader recomputes them with :func:`vdtutorial.experiments.effects.holm_rejections`.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import numpy as np

from vdtutorial.course.checks import Check, Failures
from vdtutorial.experiments.effects import holm_rejections, verdict, welch_interval

#: The exercises' default confidence (welch_verdict) and alpha (holm), as their signatures in the chapter give them.
CONFIDENCE, ALPHA = 0.95, 0.05
#: Fixed cases of 10.1 (a, b, direction): not confirmed, contradicted, confirmed.
_FIXED = (
    ([3.0, 4.0, 5.0], [1.0, 2.0, 3.0], 1),
    ([10.0, 11.0, 12.0], [1.0, 2.0, 3.0], -1),
    ([10.0, 11.0, 12.0], [1.0, 2.0, 3.0], 1),
)


def welch_inputs(rng: np.random.Generator) -> dict:
    """Ten random comparisons (the first four at the default confidence) and the fixed ones."""
    cases = {}
    for k in range(10):
        n_a, n_b = rng.integers(3, 13, 2)
        cases[f"case{k}"] = {
            "a": rng.normal(rng.uniform(-4, 4), rng.uniform(0.3, 3), n_a),
            "b": rng.normal(0, rng.uniform(0.3, 3), n_b),
            "direction": int(rng.choice([-1, 1])),
            "default": k < 4,
            "confidence": CONFIDENCE if k < 4 else float(rng.uniform(0.5, 0.99)),
        }
    for k, (a, b, direction) in enumerate(_FIXED, start=10):
        cases[f"case{k}"] = {
            "a": np.array(a),
            "b": np.array(b),
            "direction": direction,
            "default": True,
            "confidence": CONFIDENCE,
        }
    return cases


def welch_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        a, b, direction = [float(x) for x in case["a"]], [float(x) for x in case["b"]], int(case["direction"])
        found = (
            namespace["welch_verdict"](a, b, direction)
            if bool(case["default"])
            else namespace["welch_verdict"](a, b, direction, confidence=float(case["confidence"]))
        )
        out[key] = {"interval": [float(x) for x in found[:3]], "verdict": str(found[3])}
    return out


def welch_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs, key=lambda k: int(k[4:])):
        case, got, where = inputs[key], outputs[key], f"comparison {key[4:]}"
        estimate, low, high = welch_interval(case["a"], case["b"], float(case["confidence"]))
        interval = np.asarray(got["interval"], dtype=float)
        failures.close(interval[:1], [estimate], f"{where}: the estimate mean(a) - mean(b)", 1e-9, 1e-12)
        failures.close(interval[1:], [low, high], f"{where}: Welch's t interval at the given confidence", 1e-9, 1e-12)
        failures.true(
            str(got["verdict"]) == verdict(low, high, int(case["direction"])),
            f"{where}: the verdict, read in the claim's direction",
        )
    return failures


def holm_inputs(rng: np.random.Generator) -> dict:
    """Families of each size 0, 1, 2, 5 and 9, several of each, some with NaN p-values, at alpha 0.05 (the default)
    or a random one; and the chapter's own case of a NaN before a small p-value."""
    cases, k = {}, 0
    for m in (0, 1, 2, 5, 9):
        for _ in range(20 if m else 1):
            p = rng.uniform(0, 0.08, m) ** rng.uniform(1, 3)
            p[rng.random(m) < 0.1] = np.nan
            default = bool(rng.random() < 0.5)
            alpha = ALPHA if default else float(rng.uniform(0.01, 0.2))
            cases[f"case{k}"] = {"p": p, "default": default, "alpha": alpha}
            k += 1
    cases[f"case{k}"] = {"p": np.array([np.nan, 0.001]), "default": True, "alpha": ALPHA}
    return cases


def holm_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        p = [float(x) for x in case["p"]]
        found = namespace["holm"](p) if bool(case["default"]) else namespace["holm"](p, float(case["alpha"]))
        out[key] = {"is_list": isinstance(found, list), "rejected": [float(x) for x in found]}
    return out


def holm_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs, key=lambda k: int(k[4:])):
        case, got, where = inputs[key], outputs[key], f"family {key[4:]}"
        want = holm_rejections([float(x) for x in case["p"]], float(case["alpha"]))
        failures.true(got["is_list"], f"{where}: return a list, one entry per p-value")
        failures.equal(
            np.asarray(got["rejected"], dtype=float).reshape(-1),
            np.asarray(want, dtype=float),
            f"{where}: the rejections (in the order of p_values)",
        )
    return failures


CHECKS = [
    Check("ch10_welch_verdict", welch_inputs, welch_probe, welch_verdict),
    Check("ch10_holm", holm_inputs, holm_probe, holm_verdict),
]
