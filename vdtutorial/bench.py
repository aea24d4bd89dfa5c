"""Benchmarks a learner waits for, measured on the machine at hand (``python -m vdtutorial bench ...``).

``env``: environment steps per second for each task x observation mode x image size, in one process
and with two worker processes (gymnasium's AsyncVectorEnv), and the IK expert's time per action.
"""
from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert
from vdtutorial.settings import budget

#: (task, obs_mode, image_size) rows of the env benchmark.
ENV_CASES = (
    ("reach", "state", 128), ("reach", "rgbd", 64), ("reach", "rgbd", 128),
    ("grasp", "state", 256), ("grasp", "rgbd", 128), ("grasp", "rgbd", 256),
)


def _make(task: str, obs_mode: str, image_size: int):
    return lambda: gym.make(ENV_IDS[task], obs_mode=obs_mode, image_size=image_size)


def env_steps_per_second(task: str, obs_mode: str, image_size: int, steps: int, workers: int = 1, seed: int = 0) -> float:
    """Random-action steps per second; with ``workers > 1`` an AsyncVectorEnv of that many envs
    (each vector step counts ``workers`` env steps)."""
    rng = np.random.default_rng(seed)
    if workers == 1:
        env = _make(task, obs_mode, image_size)()
        env.reset(seed=seed)
        start = time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(rng.uniform(-0.6, 0.6, 6))
            if term or trunc:
                env.reset()
        elapsed = time.perf_counter() - start
        env.close()
        return steps / elapsed
    venv = gym.vector.AsyncVectorEnv([_make(task, obs_mode, image_size)] * workers)
    venv.reset(seed=seed)
    n = max(1, steps // workers)
    start = time.perf_counter()
    for _ in range(n):
        venv.step(rng.uniform(-0.6, 0.6, (workers, 6)))
    elapsed = time.perf_counter() - start
    venv.close()
    return n * workers / elapsed


def expert_timing(task: str, episodes: int, seed: int = 0) -> dict:
    """Mean time of one expert action (eqs. 9-10) and of building G for a cup, in milliseconds."""
    env = gym.make(ENV_IDS[task], obs_mode="state")
    expert = IKExpert(env)
    t_action = t_set = 0.0
    n_actions = 0
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        start = time.perf_counter()
        expert.reset()
        t_set += time.perf_counter() - start
        while True:
            start = time.perf_counter()
            a = expert.action()
            t_action += time.perf_counter() - start
            n_actions += 1
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                break
    env.close()
    return {"action_ms": 1e3 * t_action / n_actions, "solution_set_ms": 1e3 * t_set / episodes}


def bench_env(steps: int | None = None) -> list[dict]:
    """All rows of the env benchmark, printed as they come."""
    steps = steps or budget(3000, 300)
    rows = []
    print(f"{'task':6} {'obs':6} {'size':>5} {'1 proc steps/s':>15} {'2 workers steps/s':>18}")
    for task, obs_mode, size in ENV_CASES:
        one = env_steps_per_second(task, obs_mode, size, steps)
        two = env_steps_per_second(task, obs_mode, size, steps, workers=2)
        rows.append({"task": task, "obs_mode": obs_mode, "image_size": size, "steps_per_s": one, "steps_per_s_2workers": two})
        print(f"{task:6} {obs_mode:6} {size:>5} {one:>15.0f} {two:>18.0f}", flush=True)
    for task in ENV_IDS:
        t = expert_timing(task, budget(50, 5))
        rows.append({"task": task, "expert": True, **t})
        print(f"expert {task}: {t['action_ms']:.3f} ms per action, {t['solution_set_ms']:.1f} ms to build G per cup")
    return rows
