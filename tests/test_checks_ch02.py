"""Chapter 02's trusted checks (vdtutorial/course/checks/ch02.py), run as the grader runs them: the teacher's answers
pass on every seed tried; the graders' wrong answer, other plausible mistakes and an unsolved stub fail, in words that
give no number away."""

import math

import numpy as np
import pytest

from check_support import answers, assert_mistake_fails, assert_passes, executed
from vdtutorial.course import checks
from vdtutorial.course.checks import ch02
from vdtutorial.envs.base import MAX_DELTA
from vdtutorial.expert import CONTINUOUS, DISTINCT, REST_POSES, nearest_goal, solve_ik

#: What the answer cells use from the chapter's first cell.
CONTEXT = {
    "np": np,
    "math": math,
    "MAX_DELTA": MAX_DELTA,
    "CONTINUOUS": CONTINUOUS,
    "DISTINCT": DISTINCT,
    "REST_POSES": REST_POSES,
    "solve_ik": solve_ik,
}
ANSWERS = answers("02_ik_expert")
#: Per exercise: the graders' wrong answer (chapter 02 has one) and other plausible mistakes, as (old, new) edits of
#: the teacher's solution.
MISTAKES = {
    "ch02_goal_set": {
        "every verified answer kept": ("if all(np.max(np.abs(q - g)) > DISTINCT for g in found):", "if True:"),
        "no shape when G is empty": ("return np.array(found).reshape(-1, 6)", "return np.array(found)"),
        "the targets gone through once per rest pose": (
            "for position, orientation in targets:\n        for rest in REST_POSES:",
            "for rest in REST_POSES:\n        for position, orientation in targets:",
        ),
    },
    "ch02_nearest_goal": {
        "no wrap-around": ("for i in np.flatnonzero(CONTINUOUS):", "for i in []:"),
        "wrap-around beyond the limits": (
            "min(max(round((j[i] - g[i]) / turn), k_low), k_high)",
            "round((j[i] - g[i]) / turn)",
        ),
        "G changed in place": ("np.array(G, dtype=float)", "np.asarray(G, dtype=float)"),
        "the last one on a tie": ("int(np.argmin(distances))", "len(distances) - 1 - int(np.argmin(distances[::-1]))"),
    },
    "ch02_step_towards": {
        "graders' wrong answer": ("diff * min(1.0, MAX_DELTA / largest)", "diff * MAX_DELTA / largest"),
        "each joint clipped on its own": (
            "diff * min(1.0, MAX_DELTA / largest)",
            "np.clip(diff, -MAX_DELTA, MAX_DELTA)",
        ),
    },
}


@pytest.mark.parametrize(
    "exercise, seeds", [("ch02_goal_set", range(3)), ("ch02_nearest_goal", range(20)), ("ch02_step_towards", range(20))]
)
def test_the_teachers_answer_passes(exercise, seeds):
    assert_passes(exercise, CONTEXT, ANSWERS[exercise], seeds)


@pytest.mark.parametrize("exercise, mistake", [(e, m) for e, ms in MISTAKES.items() for m in [*ms, "stub"]])
def test_mistakes_fail_without_giving_numbers_away(exercise, mistake):
    assert_mistake_fails(exercise, CONTEXT, ANSWERS[exercise], MISTAKES[exercise], mistake)


def test_the_constructed_cases_are_what_they_claim():
    """Whatever the seed: each goal one turn away is the one eq. 9 picks (and plain L1 does not), each tie is exact
    and eq. 9 picks its first goal, and the goal sets of the two cups are not empty."""
    for seed in range(20):
        inputs = checks.nested(checks.plain(ch02.nearest_inputs(np.random.default_rng(seed))))
        for case in inputs["cases"].values():
            G, j, kind = case["G"], case["j"], str(case["kind"])
            plain = np.abs(G - j).sum(axis=1)
            picked = nearest_goal(G, j, inputs["lower"], inputs["upper"])
            if kind == "turn":
                assert np.abs(picked - j).sum() < 0.1 and plain.min() > 1, seed
            if kind == "tie":
                assert plain[0] == plain[1] and np.array_equal(picked, G[0]), seed
    goal_sets = ch02.goal_set_inputs(np.random.default_rng(0))
    probe = ch02.goal_set_probe(executed(CONTEXT, ANSWERS["ch02_goal_set"]), checks.nested(checks.plain(goal_sets)))
    assert [len(probe[f"set{k}"]) > 0 for k in range(6)] == [True] * 4 + [False] * 2
