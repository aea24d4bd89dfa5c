"""Chapter 10's trusted checks (vdtutorial/course/checks/ch10.py): the teacher's solutions pass them on every seed;
the graders' deliberately wrong answer, other plausible mistakes and an unsolved stub lose their exercise; the
feedback names no number."""

import math

import numpy as np
import pytest
from scipy import stats

from check_support import UNSOLVED, answers, changed, executed, failures, stub

ANSWERS = answers("10_what_reproduced")
#: What the answer cells use from the chapter's first cells.
CONTEXT = {"math": math, "np": np, "stats": stats}


def run(exercise: str, source: str, seed: int) -> list[str]:
    """The grader's steps (inputs from a fresh seed, the probe, the verdict) on a namespace holding ``source``."""
    return failures(exercise, executed(CONTEXT, source), seed)


WELCH, HOLM = ANSWERS["ch10_welch_verdict"], ANSWERS["ch10_holm"]


@pytest.mark.parametrize("seed", range(6))
def test_the_teachers_solutions_pass(seed):
    assert run("ch10_welch_verdict", WELCH, seed) == []
    assert run("ch10_holm", HOLM, seed) == []


@pytest.mark.parametrize(
    "old, new",
    [
        ("stats.t.ppf((1 + confidence) / 2, dof)", "stats.t.ppf(confidence, dof)"),  # the graders' wrong answer
        ("stats.t.ppf((1 + confidence) / 2, dof)", "stats.t.ppf(0.975, dof)"),  # ignores the confidence
        (".var(ddof=1)", ".var()"),  # the biased variance
        (
            "dof = (va + vb) ** 2",
            "dof = len(a) + len(b) - 2 + 0 * (va + vb) ** 2",
        ),  # the pooled test's degrees of freedom
        ("if direction > 0 else", "if True else"),  # ignores the claim's direction
    ],
)
def test_wrong_welch_loses(old, new):
    assert run("ch10_welch_verdict", changed(WELCH, old, new), 0)


@pytest.mark.parametrize(
    "old, new",
    [
        ("alpha / (m - rank)", "alpha / m"),  # Bonferroni, not Holm
        ("        break\n", "        continue\n"),  # no stop at the first kept claim
        ("math.isnan(p_values[i]) or ", ""),  # NaN p-values rejected
        ("return rejected", "return tuple(rejected)"),  # not a list
    ],
)
def test_wrong_holm_loses(old, new):
    assert run("ch10_holm", changed(HOLM, old, new), 0)


def test_unsolved_stubs_lose():
    for exercise, source in (("ch10_welch_verdict", WELCH), ("ch10_holm", HOLM)):
        assert run(exercise, stub(source), 0) == UNSOLVED
