"""Running a controller in an environment and counting what the paper counts.

The paper's reaching metric is the number of successful trajectories per episode of 200 time steps
(Figs. 4-6): run the controller for 200 environment steps, starting a new trajectory whenever one
ends, and count the trajectories that ended in success.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert


def expert_success_rate(task: str, episodes: int, seed: int = 0) -> tuple[float, float]:
    """Fraction of noiseless expert trajectories that succeed, and their mean length in steps.
    Trajectory ``k`` uses cup seed ``seed + k``."""
    env = gym.make(ENV_IDS[task], obs_mode="state")
    expert = IKExpert(env)
    successes, lengths = 0, []
    for k in range(episodes):
        env.reset(seed=seed + k)
        expert.reset()
        for t in range(1, 10**6):
            _, _, terminated, truncated, info = env.step(expert.action())
            if terminated or truncated:
                break
        successes += bool(info["is_success"])
        lengths.append(t)
    env.close()
    return successes / episodes, float(np.mean(lengths))
