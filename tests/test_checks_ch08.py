"""Chapter 08's trusted checks (vdtutorial/course/checks/ch08.py): the teacher's solutions pass them on every seed;
the graders' deliberately wrong answer, other plausible mistakes and an unsolved stub lose their exercise; the
feedback names no number."""

import math

import numpy as np
import pytest

from check_support import UNSOLVED, answers, changed, executed, failures, stub
from vdtutorial.envs.grasp import GRASP_HEIGHT, POSITION_TOLERANCE, TILT_TOLERANCE_DEG
from vdtutorial.trpo import TRPOConfig

ANSWERS = answers("08_grasping")
#: What the answer cells use from the chapter's first cells.
CONTEXT = {
    "math": math,
    "np": np,
    "GRASP_HEIGHT": GRASP_HEIGHT,
    "POSITION_TOLERANCE": POSITION_TOLERANCE,
    "TILT_TOLERANCE_DEG": TILT_TOLERANCE_DEG,
    "gamma": TRPOConfig().gamma,
}


def run(exercise: str, source: str, seed: int) -> list[str]:
    """The grader's steps (inputs from a fresh seed, the probe, the verdict) on a namespace holding ``source``."""
    return failures(exercise, executed(CONTEXT, source), seed)


SUCCESS, TRAJECTORY = ANSWERS["ch08_grasp_success"], ANSWERS["ch08_trajectory_return"]


@pytest.mark.parametrize("seed", range(4))
def test_the_teachers_solutions_pass(seed):
    assert run("ch08_grasp_success", SUCCESS, seed) == []
    assert run("ch08_trajectory_return", TRAJECTORY, seed) == []


@pytest.mark.parametrize(
    "old, new",
    [
        ("min(1.0, abs(approach[2]))", "min(1.0, approach[2])"),  # the graders' wrong answer
        ("math.asin(", "math.acos("),  # the angle to the vertical
        (" + np.array([0.0, 0.0, GRASP_HEIGHT])", ""),  # the cup's base, not its grasp point
        ("tilt < TILT_TOLERANCE_DEG", "tilt <= 2 * TILT_TOLERANCE_DEG"),  # too lenient on the tilt
    ],
)
def test_wrong_grasp_success_loses(old, new):
    assert run("ch08_grasp_success", changed(SUCCESS, old, new), 0)


@pytest.mark.parametrize(
    "old, new",
    [
        ("deterministic=True", "deterministic=False"),  # sampled actions, not the mean
        ("gamma ** t * r", "gamma ** (t + 1) * r"),  # discounting starts one step late
        ("env.reset(seed=seed)", "env.reset()"),  # another cup than the seed's
        ('"collision" if info["is_failure"] else "time out"', '"time out"'),  # collisions counted as time-outs
    ],
)
def test_wrong_trajectory_loses(old, new):
    assert run("ch08_trajectory_return", changed(TRAJECTORY, old, new), 0)


def test_unsolved_stubs_lose():
    for exercise, source in (("ch08_grasp_success", SUCCESS), ("ch08_trajectory_return", TRAJECTORY)):
        assert run(exercise, stub(source), 0) == UNSOLVED
