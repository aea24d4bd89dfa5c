"""Gymnasium contract and task behaviour of the two environments."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vdtutorial  # noqa: F401  (registers the ids)
from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.base import HORIZON, MAX_DELTA
from vdtutorial.envs.grasp import POSITION_TOLERANCE, grasp_point
from vdtutorial.envs.reach import C_FAILURE, C_SUCCESS, reach_goal
from vdtutorial.envs.scene import HOME
from vdtutorial.expert import IKExpert

IDS = list(ENV_IDS.values())


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("obs_mode", ["state", "rgbd"])
def test_check_env(env_id, obs_mode):
    env = gym.make(env_id, obs_mode=obs_mode, image_size=32, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_observation_shapes_and_render(env_id):
    env = gym.make(env_id, obs_mode="rgbd", image_size=48, render_mode="rgb_array")
    obs, _ = env.reset(seed=1)
    assert obs["rgb"].shape == (3, 48, 48) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (48 * 48,) and obs["depth"].dtype == np.float32
    assert obs["joints"].shape == (6,)
    np.testing.assert_allclose(obs["joints"], HOME, atol=1e-6)
    rgb, depth = obs["rgb"], obs["depth"].reshape(48, 48)
    assert rgb.max() > rgb.min()  # a real picture, not a blank frame
    assert 0.3 < depth.min() and depth.max() <= 3.0  # metres: nothing nearer than 30 cm to the camera
    frame = env.render()
    assert frame.shape == (48, 48, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, rgb.transpose(1, 2, 0))  # the observation is the camera's picture
    env.close()
    env.close()  # closing twice is fine


def test_default_image_sizes_follow_the_paper():
    for env_id, size in ((ENV_IDS["reach"], 128), (ENV_IDS["grasp"], 256)):
        env = gym.make(env_id)
        assert env.observation_space["rgb"].shape == (3, size, size)
        assert env.observation_space["depth"].shape == (size * size,)
        env.close()


@pytest.mark.parametrize("obs_mode", ["state", "rgbd"])
def test_same_seed_same_actions_same_observations(obs_mode):
    def rollout():
        env = gym.make(ENV_IDS["reach"], obs_mode=obs_mode, image_size=32)
        obs, _ = env.reset(seed=7)
        out = [obs]
        rng = np.random.default_rng(3)
        for _ in range(6):
            obs, *_ = env.step(rng.uniform(-0.3, 0.3, 6))
            out.append(obs)
        env.close()
        return out

    for a, b in zip(rollout(), rollout()):
        if obs_mode == "state":
            np.testing.assert_array_equal(a, b)
        else:
            for k in a:
                np.testing.assert_array_equal(a[k], b[k])


def test_cup_positions_come_from_the_seeded_generator():
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    cups = [env.reset(seed=s)[0][6:] for s in (0, 1, 0)]
    np.testing.assert_array_equal(cups[0], cups[2])
    assert not np.allclose(cups[0], cups[1])
    assert np.all(cups[0][:2] >= [0.3, -0.25]) and np.all(cups[0][:2] <= [0.6, 0.25])
    env.close()


def test_bad_actions_raise_and_large_ones_are_clipped():
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        env.step([0, 0, np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        env.step([0, 0, np.inf, 0, 0, 0])
    obs, reward, *_ = env.step([0.0, 0.0, 0.0, 0.0, 0.0, 10.0])
    np.testing.assert_allclose(obs[5] - HOME[5], MAX_DELTA, atol=1e-6)
    env.close()


def test_joint_limits_are_respected():
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(10):
        obs, *_ = env.step([0, 0, 0, 0, -MAX_DELTA, 0])  # joint 5 down to its lower limit
    assert obs[4] >= base.scene.lower[4] - 1e-6
    np.testing.assert_allclose(obs[4], base.scene.lower[4], atol=1e-6)
    env.close()


@pytest.mark.parametrize("task", sorted(ENV_IDS))
def test_the_env_itself_truncates_at_the_horizon(task):
    """The horizon is said once, in the env: no TimeLimit wrapper counts the steps again."""
    env = gym.make(ENV_IDS[task], obs_mode="state")
    assert env.spec.max_episode_steps is None
    env.reset(seed=0)
    for t in range(1, HORIZON + 1):
        _, _, terminated, truncated, _ = env.step(np.zeros(6))
        assert not terminated
        assert truncated == (t == HORIZON)
    env.close()


def test_reach_reward_is_eq_11():
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    env.reset(seed=0)
    a = np.array([0.1, -0.1, 0.05, 0.0, 0.0, 0.0])
    _, reward, terminated, _, info = env.step(a)
    assert not terminated
    assert reward == pytest.approx(-np.linalg.norm(a) - info["distance"])
    tcp, _ = env.unwrapped.scene.tcp_pose()
    assert info["distance"] == pytest.approx(np.linalg.norm(tcp - reach_goal(env.unwrapped.cup_position)))
    env.close()


def expert_episode(task: str):
    """Run the IK expert on cup seed 0 until the trajectory ends; the env and the last step's results."""
    env = gym.make(ENV_IDS[task], obs_mode="state")
    env.reset(seed=0)
    expert = IKExpert(env)
    expert.reset()
    for _ in range(HORIZON):
        a = expert.action()
        _, reward, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break
    return env, a, reward, terminated, info


def test_reach_success_and_failure_terminate_with_their_rewards():
    env, a, reward, terminated, info = expert_episode("reach")
    assert info["is_success"] and terminated and not info["is_failure"]
    assert reward == pytest.approx(-np.linalg.norm(a) - info["distance"] + C_SUCCESS)
    env.reset(seed=0)
    # tip the shoulder forward until the hand hits the table
    for _ in range(5):
        _, reward, terminated, _, info = env.step([0, MAX_DELTA, 0, 0, 0, 0])
        if terminated:
            break
    assert info["is_failure"] and not info["is_success"]
    assert reward == pytest.approx(-MAX_DELTA - info["distance"] - C_FAILURE)
    env.close()


def test_grasp_cup_is_an_obstacle_and_reward_is_sparse():
    env = gym.make(ENV_IDS["grasp"], obs_mode="state")
    env.reset(seed=0, options={"cup_xy": (0.45, 0.0)})
    _, reward, terminated, _, _ = env.step(np.zeros(6))
    assert reward == -1.0 and not terminated
    low_hand = HOME.copy()
    low_hand[1] = 4.23  # shoulder tipped forward: the hand 10 cm above the table, clear of it

    def hand_in_cup(env):
        scene = env.unwrapped.scene
        scene.set_joints(low_hand)
        assert not scene.in_collision()
        scene.set_cup(scene.tcp_pose()[0][:2])  # the cup where the hand is
        return scene.in_collision()

    assert hand_in_cup(env)
    env.close()
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    env.reset(seed=0)
    assert not hand_in_cup(env)  # the reaching task's cup is not an obstacle
    env.close()


def test_grasp_success_gives_25_minus_step_cost():
    env, _, reward, _, info = expert_episode("grasp")
    assert info["is_success"]
    assert reward == 24.0
    tcp, _ = env.unwrapped.scene.tcp_pose()
    assert np.linalg.norm(tcp - grasp_point(env.unwrapped.cup_position)) < POSITION_TOLERANCE
    env.close()


def test_grasp_success_region_is_collision_free():
    """The stated tolerance is the real one: at the expert's grasp poses the arm keeps at least
    POSITION_TOLERANCE from the cup and the table, so every hand position within it is collision-free
    (the budget in envs/grasp.py: 2.4 cm from the cup, 2.5 cm from the table). And
    no joint-space neighbour of a grasp pose that the env counts as a success is in collision."""
    import pybullet as p

    def gap(scene, body):
        points = p.getClosestPoints(scene.arm, body, 0.5, physicsClientId=scene.client)
        return min(c[8] for c in points if c[3] != -1)  # the base stands on the table

    rng = np.random.default_rng(0)
    for seed in (0, 1):
        env = gym.make(ENV_IDS["grasp"], obs_mode="state")
        env.reset(seed=seed)
        expert = IKExpert(env)
        expert.reset()
        for _ in range(HORIZON):
            _, _, terminated, truncated, info = env.step(expert.action())
            if terminated or truncated:
                break
        assert info["is_success"]
        base = env.unwrapped
        scene = base.scene
        cup_gap, table_gap = gap(scene, scene.cup), gap(scene, scene.table)
        assert POSITION_TOLERANCE <= cup_gap == pytest.approx(0.024, abs=0.001)
        assert POSITION_TOLERANCE <= table_gap == pytest.approx(0.025, abs=0.001)
        grasp = scene.joints.copy()
        successes = 0
        for _ in range(300):
            scene.set_joints(grasp + rng.normal(0.0, 0.02, size=6))
            success, _ = base._goal_status()
            if success:
                successes += 1
                assert not scene.in_collision()
        assert successes > 50  # the check saw many success states, not a handful
        env.close()


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="obs_mode"):
        gym.make(ENV_IDS["reach"], obs_mode="pixels")
    with pytest.raises(ValueError, match="image_size"):
        gym.make(ENV_IDS["reach"], image_size=3)
    with pytest.raises(ValueError, match="render_mode"):
        gym.make(ENV_IDS["reach"], render_mode="ansi")
