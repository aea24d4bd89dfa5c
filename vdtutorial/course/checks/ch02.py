"""Trusted checks of chapter 02's exercises: the goal set G (2.1), eq. 9's nearest goal (2.2), eq. 10's step (2.3).

The grader draws cups (and their target hand poses), goal sets and joint angles; the kernel returns what the
student's functions gave for them, and the grader recomputes each with the library's ``solution_set``,
``nearest_goal`` and ``step_towards`` (:mod:`vdtutorial.expert`). The goal sets are solved in a reaching scene of
each process's own (:func:`vdtutorial.course.checks.ch01.environment`).

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import math

import numpy as np

from vdtutorial.course.checks import Check, Failures, failing
from vdtutorial.course.checks.ch01 import LIMITED, environment
from vdtutorial.envs.scene import CUP_REGION_HIGH, CUP_REGION_LOW, HOME
from vdtutorial.expert import CONTINUOUS, grasp_targets, nearest_goal, reach_targets, solution_set, step_towards


def _scene(owner: str):
    return environment("reach", owner).unwrapped.scene


# -- Exercise 2.1: the goal set G ---------------------------------------------------------------------------------
def goal_set_inputs(rng: np.random.Generator) -> dict:
    """For two random cups, the reaching and the grasping target hand poses; one set out of the arm's reach (an
    empty G) and an empty set of targets."""
    sets, cups = {}, rng.uniform(CUP_REGION_LOW, CUP_REGION_HIGH, (2, 2))
    for k, (cup, targets) in enumerate([(cup, make) for cup in cups for make in (reach_targets, grasp_targets)]):
        poses = list(targets(np.append(cup, 0.0)))
        sets[f"set{k}"] = {
            "cup_xy": cup,
            "positions": np.array([p for p, _ in poses]),
            "orientations": np.array([o for _, o in poses]),
        }
    far = sets["set0"]
    sets["set4"] = {**far, "positions": far["positions"] + [rng.uniform(1.5, 2.5), 0.0, 0.0]}
    sets["set5"] = {"cup_xy": cups[0], "positions": np.zeros((0, 3)), "orientations": np.zeros((0, 4))}
    return sets


def _targets(case) -> list:
    return [(position, tuple(orientation)) for position, orientation in zip(case["positions"], case["orientations"])]


def goal_set_probe(namespace: dict, inputs: dict) -> dict:
    scene, out = _scene("probe"), {}
    for key in sorted(inputs):
        scene.set_cup(inputs[key]["cup_xy"])
        scene.set_joints(HOME)
        out[key] = np.asarray(namespace["my_goal_set"](scene, iter(_targets(inputs[key]))), dtype=float)
    return out


def goal_set_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures, scene = Failures(), _scene("grader")
    for key in sorted(inputs):
        scene.set_cup(inputs[key]["cup_xy"])
        scene.set_joints(HOME)
        want, got, where = solution_set(scene, _targets(inputs[key])), outputs[key], f"target set {key[3:]}"
        shape = (
            f"{where}: no target gives a verified answer here, so G is empty, an array with one column per joint"
            if len(want) == 0
            else f"{where}: G has the wrong number of rows or columns (every target tried "
            "from every rest pose, going through the targets once; each distinct posture once, one row of "
            "joint angles)"
        )
        if failures.true(np.shape(got) == want.shape, shape):
            failures.close(got, want, f"{where}: the same postures, in the order found", 0, 1e-9)
    return failures


# -- Exercise 2.2: eq. 9 with wrap-around joints ------------------------------------------------------------------
#: The kinds of cases of Exercise 2.2, as the verdict names them.
_NEAREST = {
    "within": "joint angles anywhere within the limits",
    "edge": "joint angles near the limits",
    "turn": "a goal one turn away on a continuous joint",
    "tie": "a tie between two goals",
}


def _one_turn_away(rng, lower, upper):
    """Random goals and, among them, the posture of joint angles j with a continuous joint's angle a turn away (the
    continuous joints' limits are +-2 pi: one of the two turns stays within them)."""
    j = rng.uniform(lower + 0.1, upper - 0.1)
    goal = j + rng.normal(0, 0.01, 6)
    i = rng.choice(np.flatnonzero(CONTINUOUS))
    goal[i] -= math.copysign(2 * math.pi, goal[i])
    G = rng.uniform(lower, upper, (int(rng.integers(1, 6)), 6))
    return np.insert(G, rng.integers(len(G) + 1), goal, axis=0), j


def _tie(rng, lower, upper):
    """Two goals at exactly the same L1 distance from j (numbers exact in binary), on different joints."""
    j = np.round(rng.uniform(lower + 0.5, upper - 0.5) * 8) / 8
    first, second = rng.choice(LIMITED, 2, replace=False)
    G = np.array([j, j])
    G[0, first] += 0.25
    G[1, second] -= 0.25
    return G, j


def nearest_inputs(rng: np.random.Generator) -> dict:
    """Random goal sets of one to eight members with 20 joint angles within the limits, 20 near the limits (where
    the wrap-around is limited), 5 constructed goals one turn away and 3 ties; the scene's joint limits."""
    scene = _scene("grader")
    lower, upper = scene.lower.copy(), scene.upper.copy()
    cases = {}
    for k in range(48):
        if k < 40:
            G = rng.uniform(lower, upper, (int(rng.integers(1, 9)), 6))
            j = (
                rng.uniform(lower, upper)
                if k < 20
                else np.clip(rng.choice([-1, 1], 6) * rng.uniform(4.0, 6.5, 6), lower, upper)
            )
        else:
            G, j = (_one_turn_away if k < 45 else _tie)(rng, lower, upper)
        cases[f"case{k}"] = {
            "G": G,
            "j": j,
            "kind": "within" if k < 20 else "edge" if k < 40 else "turn" if k < 45 else "tie",
        }
    return {"cases": cases, "lower": lower, "upper": upper}


def nearest_probe(namespace: dict, inputs: dict) -> dict:
    out, lower, upper = {}, inputs["lower"], inputs["upper"]
    for key, case in inputs["cases"].items():
        G = case["G"].copy()
        got = namespace["my_nearest_goal"](G, case["j"].copy(), lower.copy(), upper.copy())
        out[key] = {"goal": np.asarray(got, dtype=float), "G": G}
    return out


def nearest_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures, lower, upper = Failures(), inputs["lower"], inputs["upper"]
    keys = sorted(inputs["cases"], key=lambda key: int(key[4:]))
    ok, kept = [], []
    for key in keys:
        case, got = inputs["cases"][key], outputs[key]
        want = nearest_goal(case["G"], case["j"], lower, upper)
        ok.append(np.shape(got["goal"]) == (6,) and np.allclose(got["goal"], want, rtol=0, atol=1e-9))
        kept.append(np.array_equal(got["G"], case["G"]))
    kinds = np.array([str(inputs["cases"][key]["kind"]) for key in keys])
    for kind, where in _NEAREST.items():
        right = np.array(ok)[kinds == kind]
        failures.true(right, f"{where}, cases {failing(right)}: g* (six joint angles) differs from eq. 9's")
    failures.true(kept, f"cases {failing(kept)}: leave G unchanged")
    return failures


# -- Exercise 2.3: eq. 10 with the overshoot fix ------------------------------------------------------------------
#: How far the goals are from the joint angles (radians, per joint at most; a step moves a joint by up to pi/5), as
#: the verdict names them.
_SCALES = {
    0.05: "goals very near",
    0.3: "goals within one step",
    0.8: "goals about one step away",
    3.0: "goals far away",
}
#: Cases per distance.
_PER_SCALE = 10


def step_inputs(rng: np.random.Generator) -> dict:
    """Joint angles j in [-2, 2] with goals at each distance of :data:`_SCALES`, and last one goal equal to j."""
    j = rng.uniform(-2, 2, (len(_SCALES) * _PER_SCALE + 1, 6))
    offsets = [rng.uniform(-scale, scale, (_PER_SCALE, 6)) for scale in _SCALES]
    return {"goal": j + np.concatenate(offsets + [np.zeros((1, 6))]), "j": j}


def step_probe(namespace: dict, inputs: dict) -> dict:
    return {
        "step": [
            np.asarray(namespace["my_step"](goal.copy(), j.copy()), dtype=float)
            for goal, j in zip(inputs["goal"], inputs["j"])
        ]
    }


def step_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    want = np.array([step_towards(goal, j) for goal, j in zip(inputs["goal"], inputs["j"])])
    got = np.asarray(outputs["step"], dtype=float)
    if not failures.true(got.shape == want.shape, "my_step must return one change per joint"):
        return failures
    ok = np.isclose(got, want, rtol=1e-7, atol=1e-12).all(axis=1)
    for k, where in enumerate(_SCALES.values()):
        right = ok[k * _PER_SCALE : (k + 1) * _PER_SCALE]
        failures.true(right, f"{where}, cases {failing(right)}: the step differs from eq. 10 with the overshoot fix")
    failures.true(ok[-1], "at the goal the step must be zero")
    return failures


CHECKS = [
    Check("ch02_goal_set", goal_set_inputs, goal_set_probe, goal_set_verdict),
    Check("ch02_nearest_goal", nearest_inputs, nearest_probe, nearest_verdict),
    Check("ch02_step_towards", step_inputs, step_probe, step_verdict),
]
