"""Running a controller in an environment and counting what the paper counts.

The paper's reaching metric is the number of successful trajectories per episode of 200 time steps
(Figs. 4-6): run the controller for 200 environment steps, starting a new trajectory whenever one
ends, and count the trajectories that ended in success. A controller here is anything with
``reset(env)`` (called after every ``env.reset``) and ``action(obs)``.

Taught in chapter 02.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert

#: Length of the paper's evaluation episode, in environment steps.
EPISODE_STEPS = 200


class ExpertController:
    """The IK expert as a controller (it rebuilds G for every new cup)."""

    def __init__(self, env: gym.Env):
        self.expert = IKExpert(env)

    def reset(self, env) -> None:
        self.expert.reset()

    def action(self, obs) -> np.ndarray:
        return self.expert.action()


class PolicyController:
    """A Gaussian policy as a controller: its mean action when ``deterministic``, else a sample."""

    def __init__(self, policy, deterministic: bool = True):
        self.policy, self.deterministic = policy, deterministic

    def reset(self, env) -> None:
        pass

    def action(self, obs) -> np.ndarray:
        return self.policy.act(obs, deterministic=self.deterministic)


def successes_per_episode(env: gym.Env, controller, steps: int = EPISODE_STEPS, seed: int = 0) -> dict:
    """Run ``controller`` for ``steps`` env steps (new trajectory whenever one ends) and count.

    Returns successes (trajectories ending in success), failures (ending in a collision), trajectories
    finished, and the total reward."""
    obs, _ = env.reset(seed=seed)
    controller.reset(env)
    out = {"successes": 0, "failures": 0, "trajectories": 0, "reward": 0.0}
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(controller.action(obs))
        out["reward"] += float(reward)
        if terminated or truncated:
            out["trajectories"] += 1
            out["successes"] += bool(info["is_success"])
            out["failures"] += bool(info["is_failure"])
            obs, _ = env.reset()
            controller.reset(env)
    return out


def mean_action_successes(
    policy, task: str, seed: int, episodes: int, num_envs: int, obs_mode: str = "state", image_size: int = 128
) -> dict:
    """A pre-trained policy's score before RL, counted as TRPO counts an iteration: per 200-step episode,
    ``num_envs`` fresh runs of ``200 / num_envs`` steps with the policy's mean action (reset seeds derived
    from (seed, k) for episode k), on the observations the policy reads (``obs_mode``, ``image_size``).
    Returns the successes and the finished trajectories per episode, averaged over ``episodes`` episodes."""
    env = gym.make(ENV_IDS[task], obs_mode=obs_mode, image_size=image_size)
    controller, totals = PolicyController(policy, deterministic=True), {"successes": 0, "trajectories": 0}
    for k in range(episodes):
        for reset_seed in np.random.SeedSequence([seed, k]).generate_state(num_envs):
            counts = successes_per_episode(env, controller, EPISODE_STEPS // num_envs, int(reset_seed))
            totals = {key: totals[key] + counts[key] for key in totals}
    env.close()
    return {key: value / episodes for key, value in totals.items()}


def expert_success_rate(task: str, episodes: int, seed: int = 0, progress: bool = False) -> tuple[float, float]:
    """Fraction of noiseless expert trajectories that succeed, and their mean length in steps.
    Trajectory ``k`` uses cup seed ``seed + k``."""
    if int(episodes) != episodes or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    env = gym.make(ENV_IDS[task], obs_mode="state")
    expert = IKExpert(env)
    successes, lengths = 0, []
    for k in tqdm(range(episodes), desc=f"{task} expert", unit="episode", disable=not progress):
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
