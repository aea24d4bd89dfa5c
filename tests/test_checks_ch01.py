"""Chapter 01's trusted checks (vdtutorial/course/checks/ch01.py), run as the grader runs them: the teacher's answers
pass on every seed tried; the graders' wrong answer, other plausible mistakes and an unsolved stub fail, in words that
give no number away."""

import math

import numpy as np
import pytest

from check_support import answers, assert_mistake_fails, assert_passes
from vdtutorial.course import checks
from vdtutorial.course.checks import ch01
from vdtutorial.envs.grasp import POSITION_TOLERANCE, TILT_TOLERANCE_DEG, grasp_point
from vdtutorial.envs.reach import C_FAILURE, C_SUCCESS, SUCCESS_TOLERANCE, reach_goal

#: What the answer cells use from the chapter's first cells.
CONTEXT = {
    "np": np,
    "math": math,
    "reach_goal": reach_goal,
    "SUCCESS_TOLERANCE": SUCCESS_TOLERANCE,
    "C_SUCCESS": C_SUCCESS,
    "C_FAILURE": C_FAILURE,
    "grasp_point": grasp_point,
    "POSITION_TOLERANCE": POSITION_TOLERANCE,
    "TILT_TOLERANCE_DEG": TILT_TOLERANCE_DEG,
}
ANSWERS = answers("01_environment")
#: Per exercise: the graders' wrong answer (chapter 01 has one) and other plausible mistakes, as (old, new) edits of
#: the teacher's solution.
MISTAKES = {
    "ch01_reward_eq11": {
        "graders' wrong answer": ('"-d_t": -distance,', '"-d_t": distance,'),
        "no joint limits": ("np.clip(q_old + action, scene.lower, scene.upper)", "q_old + action"),
        "L1 length of the action": ("-float(np.linalg.norm(action))", "-float(np.abs(action).sum())"),
    },
    "ch01_collision_share": {
        "truncation counted as a collision": ('"failure" if info["is_failure"] else "truncated"', '"failure"'),
        "the seed not used": ("env.reset(seed=int(seed))", "env.reset()"),
        "actions from a stale observation": (
            "obs, _, terminated, truncated, info = env.step(policy(obs))",
            "_, _, terminated, truncated, info = env.step(policy(obs))",
        ),
        # the grading kernel plays the grader's episodes back whatever the actions: they are compared on their own
        "not the policy's action": ("env.step(policy(obs))", "env.step(0.5 * policy(obs))"),
    },
    "ch01_grasp_reward": {
        "a collision does not end the episode": ("return reward, success or bool(failure)", "return reward, success"),
        "the approach axis's sign": ("min(1.0, abs(float(approach[2])))", "min(1.0, float(approach[2]))"),
        "tilt from the vertical": ("math.asin(", "math.acos("),
    },
}


@pytest.mark.parametrize(
    "exercise, seeds",
    [("ch01_reward_eq11", range(6)), ("ch01_collision_share", range(3)), ("ch01_grasp_reward", range(6))],
)
def test_the_teachers_answer_passes(exercise, seeds):
    assert_passes(exercise, CONTEXT, ANSWERS[exercise], seeds)


@pytest.mark.parametrize("exercise, mistake", [(e, m) for e, ms in MISTAKES.items() for m in [*ms, "stub"]])
def test_mistakes_fail_without_giving_numbers_away(exercise, mistake):
    assert_mistake_fails(exercise, CONTEXT, ANSWERS[exercise], MISTAKES[exercise], mistake)


def test_the_inputs_reach_every_outcome():
    """Whatever the seed, the steps of 1.1 include successes, collisions and a joint limit; the expert's episodes of
    1.2 include a success and the small random actions a truncation; 1.3's cases include successes, in both parts."""
    scene = ch01.environment("reach", "grader").unwrapped.scene
    grasp_env = ch01.environment("grasp", "grader").unwrapped
    for seed in range(5):
        rng = np.random.default_rng(seed)
        steps = checks.nested(checks.plain(ch01.reward_inputs(rng)))
        terms = ch01.reward_reference(steps)["terms"]
        target = steps["q"] + steps["action"]
        assert (terms[:, 2] > 0).any() and (terms[:, 3] < 0).any(), seed
        assert ((target < scene.lower) | (target > scene.upper)).any(), seed
        episodes = ch01.runner_reference(checks.nested(checks.plain(ch01.runner_inputs(rng))))
        assert episodes["expert"]["counts"][0] > 0 and episodes["narrow"]["counts"][2] > 0, seed
        grasp = checks.nested(checks.plain(ch01.grasp_inputs(rng)))
        poses = grasp["poses"]
        near = np.linalg.norm(poses["tcp"] - [grasp_point(cup) for cup in poses["cup"]], axis=1) < POSITION_TOLERANCE
        level = np.degrees(np.arcsin(np.abs(poses["approach"][:, 2]))) < TILT_TOLERANCE_DEG
        assert (near & level & (poses["failure"] == 0)).sum() >= 3, seed
        successes = 0
        for q, cup_xy, flag in zip(grasp["states"]["q"], grasp["states"]["cup_xy"], grasp["states"]["failure"]):
            grasp_env.set_state(q, cup_xy)
            successes += ch01._outcome(grasp_env, bool(flag))[0] > 0
        assert successes > 0, seed
