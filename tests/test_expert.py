"""The IK expert: the solution set G, eq. 9, eq. 10 with its overshoot fix, success rates."""

import math

import gymnasium as gym
import numpy as np
import pytest

from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.base import MAX_DELTA
from vdtutorial.envs.reach import SUCCESS_TOLERANCE, reach_goal
from vdtutorial.experiments.evaluation import expert_success_rate
from vdtutorial.expert import CONTINUOUS, DISTINCT, IKExpert, nearest_equivalent, nearest_goal, step_towards


@pytest.fixture
def reach():
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    env.reset(seed=3)
    yield env
    env.close()


def test_solution_set_is_several_distinct_valid_configurations(reach):
    G = IKExpert(reach).reset()
    scene = reach.unwrapped.scene
    assert len(G) >= 3
    for i, g in enumerate(G):
        assert np.all(g >= scene.lower) and np.all(g <= scene.upper)
        scene.set_joints(g)
        assert not scene.in_collision()
        tcp, _ = scene.tcp_pose()
        assert np.linalg.norm(tcp - reach_goal(scene.cup_position)) < SUCCESS_TOLERANCE / 2
        for h in G[:i]:
            assert np.max(np.abs(g - h)) > DISTINCT


def test_wrist_roll_variants_share_the_hand_centre():
    """The 4 wrist rolls of each tilt put the hand centre at the same goal with the same approach axis:
    they differ only in the turn about it (the choice documented in expert.py)."""
    import pybullet as p

    from vdtutorial.expert import reach_targets

    targets = list(reach_targets(np.array([0.45, 0.1, 0.0])))
    assert len(targets) == 12  # 3 tilts x 4 rolls
    axes = [np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3) for _, q in targets]
    for tilt in range(3):
        group = range(4 * tilt, 4 * tilt + 4)
        for k in group:
            np.testing.assert_allclose(targets[k][0], targets[4 * tilt][0])
            np.testing.assert_allclose(axes[k][:, 2], axes[4 * tilt][:, 2], atol=1e-9)
        ups = [axes[k][:, 1] for k in group]
        np.testing.assert_allclose([ups[0] @ u for u in ups], [1, 0, -1, 0], atol=1e-9)


def test_eq9_picks_the_nearest_in_l1():
    G = np.array([[1.0, 1, 1, 1, 1, 1], [2.0, 2, 2, 2, 2, 2]])
    lo, hi = np.full(6, -10.0), np.full(6, 10.0)
    np.testing.assert_array_equal(nearest_goal(G, np.full(6, 1.8), lo, hi), G[1])
    np.testing.assert_array_equal(nearest_goal(G, np.full(6, 1.2), lo, hi), G[0])


def test_continuous_joints_are_compared_modulo_two_pi():
    lo, hi = np.full(6, -2 * math.pi), np.full(6, 2 * math.pi)
    g = np.array([3.0, 3.0, 3.0, 3.0, 3.0, 3.0])
    j = g - 2 * math.pi + 0.1
    eq = nearest_equivalent(g, j, lo, hi)
    np.testing.assert_allclose(eq[[0, 3, 5]], j[[0, 3, 5]] - 0.1)  # continuous joints 1, 4, 6 wrap
    np.testing.assert_allclose(eq[[1, 2, 4]], g[[1, 2, 4]])  # limited joints do not


def test_nearest_equivalent_shifts_up_from_below_the_lower_limit():
    """Issue 9's case: the nearest shift of g = 6.06 towards j = -5.5 leaves the limits (-6.51), so the
    answer is the next one up, -0.22 (distance 5.28), not g itself (distance 11.56)."""
    lo, hi = np.full(6, -2 * math.pi), np.full(6, 2 * math.pi)
    eq = nearest_equivalent(np.full(6, 6.06), np.full(6, -5.5), lo, hi)
    np.testing.assert_allclose(eq[[0, 3, 5]], 6.06 - 2 * math.pi)
    np.testing.assert_allclose(np.abs(eq - (-5.5))[[0, 3, 5]], 5.5 + 6.06 - 2 * math.pi)
    np.testing.assert_array_equal(eq[[1, 2, 4]], 6.06)


def test_nearest_equivalent_matches_brute_force_over_shifts_within_limits():
    """Random goals and states within the Jaco's limits: the chosen copy of each continuous joint is in
    the limits and as near to j as the best of all in-limit copies g + 2 pi k, |k| <= 3."""
    from vdtutorial.envs.scene import JacoScene

    scene = JacoScene(16)
    lo, hi = scene.lower, scene.upper
    scene.close()
    rng = np.random.default_rng(0)
    k = np.arange(-3, 4)[:, None]
    for _ in range(2000):
        g, j = rng.uniform(lo, hi), rng.uniform(lo, hi)
        eq = nearest_equivalent(g, j, lo, hi)
        assert np.all((eq >= lo) & (eq <= hi))
        copies = g + 2 * math.pi * k
        best = np.where((copies >= lo) & (copies <= hi), np.abs(copies - j), np.inf).min(axis=0)
        np.testing.assert_allclose(np.abs(eq - j)[CONTINUOUS], best[CONTINUOUS], atol=1e-12)
        np.testing.assert_array_equal(eq[~CONTINUOUS], g[~CONTINUOUS])


def test_eq10_moves_largest_joint_by_pi_over_5_and_never_overshoots():
    j = np.zeros(6)
    far = np.array([2.0, -1.0, 0.5, 0, 0, 0])
    a = step_towards(far, j)
    assert np.max(np.abs(a)) == pytest.approx(MAX_DELTA)
    np.testing.assert_allclose(a / np.linalg.norm(a), far / np.linalg.norm(far))
    near = np.array([0.1, -0.05, 0, 0, 0, 0.02])
    np.testing.assert_allclose(step_towards(near, j), near)  # exactly onto the goal, not past it
    np.testing.assert_array_equal(step_towards(j, j), np.zeros(6))


def test_grasp_expert_action_depends_on_the_state_alone():
    """Eq. 8 labels a state with pi_exp(s): the grasp expert's action in a state must not depend on the
    states visited before, in particular not on a remembered final-approach goal."""
    env = gym.make(ENV_IDS["grasp"], obs_mode="state")
    env.reset(seed=1)
    expert = IKExpert(env)
    expert.reset()
    rng = np.random.default_rng(0)
    states, actions = [], []
    for _ in range(25):
        j = env.unwrapped.joints
        states.append(j)
        actions.append(expert.action())
        _, _, terminated, truncated, _ = env.step(actions[-1] + rng.normal(0.0, 0.01, size=6))
        if terminated or truncated:
            break
    assert any(expert.final_goal(j) is not None for j in states)  # the final approach was visited
    fresh = IKExpert(env)
    fresh.reset()
    for j, a in reversed(list(zip(states, actions))):  # another expert, another history: the same labels
        np.testing.assert_array_equal(fresh.action(j), a)
        np.testing.assert_array_equal(expert.action(j), a)
    env.close()


def test_expert_action_is_fast(reach):
    import time

    expert = IKExpert(reach)
    expert.reset()
    start = time.perf_counter()
    for _ in range(200):
        expert.action()
    assert (time.perf_counter() - start) / 200 < 1e-3


def test_expert_success_rates():
    reach_rate, _ = expert_success_rate("reach", 20, seed=100)
    grasp_rate, _ = expert_success_rate("grasp", 20, seed=100)
    assert reach_rate >= 0.95
    assert grasp_rate >= 0.85
