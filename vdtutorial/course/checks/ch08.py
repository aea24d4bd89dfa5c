"""Trusted checks of chapter 08's exercises: the grasp success test (8.1) and one trajectory's return (8.2).

8.1: hand frames near random grasp points, approach axes pointing up, down and sideways (each quaternion with a
random sign, since q and -q are the same rotation) and a few exact cases; the grader recomputes distance, tilt and
success as :class:`vdtutorial.envs.grasp.JacoGraspEnv` does. 8.2: trajectories in the grasping env from random seeds
of three policies (the IK expert, a random constant action, a slow one, so that successes, collisions and time-outs
occur), each acting with noise unless asked for its mean action. The grasping env's goal test is a stub in the
grading kernel (it is what 8.1 asks for), so the grader plays each trajectory with the mean actions in its own env
first and the kernel's env plays it back (:class:`vdtutorial.course.checks.ch01.Replay`); the kernel also returns
the start state and the actions the env got, which the grader compares with the ones that made the trajectory.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import functools
import math

import gymnasium as gym
import numpy as np
import pybullet as p

from vdtutorial.course.checks import Check, Failures
from vdtutorial.course.checks.ch01 import Replay, episode
from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.base import MAX_DELTA
from vdtutorial.envs.grasp import POSITION_TOLERANCE, TILT_TOLERANCE_DEG, grasp_point, tilt_deg
from vdtutorial.expert import IKExpert
from vdtutorial.trpo import TRPOConfig

#: Random hand frames of 8.1 (a fraction of them successes).
FRAMES = 200
#: Exact frames of 8.1 at the grasp point: approach axis horizontal, straight up, straight down.
_EXACT = ((0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)), (0.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0))
#: The policies of 8.2, as the feedback names them.
_KINDS = {"expert": "the IK expert as a policy", "constant": "a constant action", "slow": "a small constant action"}


def _quaternion(axis: np.ndarray) -> np.ndarray:
    """A unit quaternion (x, y, z, w) turning the z axis onto the unit vector ``axis``."""
    turn = np.cross([0.0, 0.0, 1.0], axis)
    half = math.acos(np.clip(axis[2], -1, 1)) / 2
    return np.append(turn / np.linalg.norm(turn) * math.sin(half), math.cos(half))


def success_inputs(rng: np.random.Generator) -> dict:
    """Random cups, hand centres around the grasp point and approach axes mostly near horizontal (either sign of
    z), then a few uniformly random orientations and the exact frames."""
    cups = rng.uniform([0.3, -0.3, 0.0], [0.6, 0.3, 0.05], (FRAMES, 3))
    tcps = grasp_point(cups) + rng.normal(0, POSITION_TOLERANCE, (FRAMES, 3))
    axes = rng.normal(size=(FRAMES, 3)) * [1.0, 1.0, 0.15]
    quaternions = np.array([_quaternion(a / np.linalg.norm(a)) for a in axes])
    quaternions[-20:] = rng.normal(size=(20, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    quaternions *= rng.choice([-1.0, 1.0], (FRAMES, 1))
    exact_cups = cups[: len(_EXACT)]
    return {
        "cups": np.concatenate([cups, exact_cups]),
        "tcps": np.concatenate([tcps, [grasp_point(c) for c in exact_cups]]),
        "quaternions": np.concatenate([quaternions, _EXACT]),
    }


def success_probe(namespace: dict, inputs: dict) -> dict:
    found = [
        namespace["grasp_success"](tcp, q, cup)
        for tcp, q, cup in zip(inputs["tcps"], inputs["quaternions"], inputs["cups"])
    ]
    return {
        "success": [bool(f[0]) for f in found],
        "distance": [float(f[1]) for f in found],
        "tilt": [float(f[2]) for f in found],
    }


def _first_wrong(failures: Failures, wrong: np.ndarray, what: str) -> None:
    if len(wrong):
        failures.append(f"{what} is wrong for some hand frames (the first: frame {int(wrong[0])})")


def success_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    distance = np.linalg.norm(inputs["tcps"] - grasp_point(inputs["cups"]), axis=1)
    approach = [np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3)[:, 2] for q in inputs["quaternions"]]
    tilt = np.array([tilt_deg(a) for a in approach])
    success = (distance < POSITION_TOLERANCE) & (tilt < TILT_TOLERANCE_DEG)
    for key, want, what, atol in (
        ("distance", distance, "the distance to the grasp point", 1e-9),
        ("tilt", tilt, "the tilt of the approach axis (degrees)", 1e-4),
        ("success", success, "the success flag", 0),
    ):
        got = np.asarray(outputs[key], dtype=float)
        if failures.true(got.shape == want.shape, f"{what}: one per hand frame"):
            _first_wrong(failures, np.flatnonzero(~(np.abs(got - want) <= atol)), what)
    return failures


@functools.lru_cache(maxsize=1)
def _grasp_env() -> gym.Env:
    """The grasping env of the checks, built once per process (the kernel's and the grader's)."""
    return gym.make(ENV_IDS["grasp"], obs_mode="state")


class _Actor:
    """A policy whose mean action is ``mean(obs)`` (the IK expert's when ``mean`` is None, with G rebuilt whenever
    the cup, the last 3 numbers of the state, changes); without ``deterministic`` it adds noise."""

    def __init__(self, env: gym.Env, constant, noise_seed: int):
        self.constant, self.expert, self.cup = constant, IKExpert(env), None
        self.rng = np.random.default_rng(noise_seed)

    def act(self, obs, deterministic=False):
        if self.constant is not None:
            action = np.array(self.constant, dtype=np.float64)
        else:
            if self.cup is None or not np.array_equal(obs[-3:], self.cup):
                self.cup = np.array(obs[-3:])
                self.expert.reset()
            action = self.expert.action()
        return action if deterministic else action + self.rng.normal(0, MAX_DELTA / 3, action.shape)


def trajectory_inputs(rng: np.random.Generator) -> dict:
    """Three random env seeds; for each, the expert, a random constant action and a slow constant action, and the
    trajectory of the policy's mean action in the grader's env (:func:`vdtutorial.course.checks.ch01.episode`)."""
    cases, env = {}, _grasp_env()
    for k, seed in enumerate(rng.choice(10**6, 3, replace=False)):
        for name, constant in (
            ("expert", None),
            ("constant", rng.uniform(-MAX_DELTA, MAX_DELTA, 6)),
            ("slow", rng.uniform(-MAX_DELTA, MAX_DELTA, 6) / 50),
        ):
            cases[f"{name}{k}"] = {
                "seed": int(seed),
                "expert": constant is None,
                "noise_seed": int(rng.integers(2**31)),
                "action": np.zeros(6) if constant is None else constant,
            }
            actor = _policy(env, cases[f"{name}{k}"])
            cases[f"{name}{k}"]["episode"] = episode(env, lambda obs: actor.act(obs, deterministic=True), seed)
    return cases


def _policy(env: gym.Env, case: dict) -> _Actor:
    return _Actor(env, None if bool(case["expert"]) else np.asarray(case["action"]), int(case["noise_seed"]))


class _Recorder(gym.Wrapper):
    """The env as the student's code gets it: notes the first state of each reset and every action taken."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.starts, self.actions = [], []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.starts.append(np.array(obs, dtype=np.float64))
        return obs, info

    def step(self, action):
        self.actions.append(np.array(action, dtype=np.float64))
        return self.env.step(action)


def trajectory_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        env = _Recorder(Replay(_grasp_env(), {str(int(case["seed"])): case["episode"]}))
        found = namespace["run_trajectory"](env, _policy(env, case), int(case["seed"]))
        out[key] = {
            "outcome": str(found["outcome"]),
            "steps": int(found["steps"]),
            "return": float(found["return"]),
            "discounted": float(found["discounted"]),
            "starts": np.array(env.starts).reshape(-1, 9),
            "actions": np.array(env.actions).reshape(-1, 6),
        }
    return out


def trajectory_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures, gamma = Failures(), TRPOConfig().gamma
    for key in sorted(inputs):
        got, where = outputs[key], f"{_KINDS[key[:-1]]}, trajectory {key[-1]}"
        played = inputs[key]["episode"]
        rewards, actions, start, info = list(played["reward"]), played["action"], played["obs"][0], played["info"]
        info = {name: values[-1] for name, values in info.items()}
        outcome = "success" if info["is_success"] else "collision" if info["is_failure"] else "time out"
        starts, taken = np.asarray(got["starts"], dtype=float), np.asarray(got["actions"], dtype=float)
        failures.true(
            len(starts) > 0 and np.allclose(starts[-1], start, rtol=0, atol=1e-9),
            f"{where}: start the trajectory with env.reset(seed=seed)",
        )
        failures.true(
            taken.shape == actions.shape and np.allclose(taken, actions, rtol=0, atol=1e-9),
            f"{where}: the actions taken must be the policy's mean actions, one per step until the end",
        )
        failures.true(str(got["outcome"]) == outcome, f"{where}: the outcome")
        failures.true(int(got["steps"]) == len(rewards), f"{where}: the number of steps")
        failures.close(got["return"], sum(rewards), f"{where}: the return", 0, 1e-9)
        failures.close(
            got["discounted"],
            sum(gamma**t * r for t, r in enumerate(rewards)),
            f"{where}: the discounted return",
            0,
            1e-9,
        )
    return failures


CHECKS = [
    Check("ch08_grasp_success", success_inputs, success_probe, success_verdict),
    Check("ch08_trajectory_return", trajectory_inputs, trajectory_probe, trajectory_verdict),
]
