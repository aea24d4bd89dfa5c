"""Step 1 of TRPO, collecting: the policy run in a vector environment for one batch (:func:`rollout`), and the vector
environment it needs (:func:`make_vec_env`). Every iteration resets the environments and draws its action noise from
seeds of (run seed, iteration) alone (:func:`iteration_seeds`), so a run resumed from a checkpoint continues exactly.

Taught in chapter 06b.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import gymnasium
import numpy as np
import torch
from torch import nn

from vdtutorial.baselines import Obs
from vdtutorial.policy import obs_to_tensor, stack_obs


def make_vec_env(
    env: str | Callable[[], gymnasium.Env], num_envs: int = 1, asynchronous: bool = False, **make_kwargs
) -> gymnasium.vector.VectorEnv:
    """A vector environment with same-step autoreset, as TRPO expects. ``env`` is a registered id (made with
    ``gymnasium.make(env, **make_kwargs)``) or a function returning an environment; ``asynchronous=True`` runs each
    copy in its own process.

    Why same-step: gymnasium >= 1.0 autoresets a finished sub-environment either on the same step (its final
    observation and info go into ``info["final_obs"]`` / ``info["final_info"]``) or on the next step (which then
    ignores the action). With ``AutoresetMode.SAME_STEP`` every step of a batch is a real transition.
    """
    make = (lambda: gymnasium.make(env, **make_kwargs)) if isinstance(env, str) else env
    vector_cls = gymnasium.vector.AsyncVectorEnv if asynchronous else gymnasium.vector.SyncVectorEnv
    return vector_cls([make] * num_envs, autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)


def check_vec_env(env: gymnasium.vector.VectorEnv, steps_per_iter: int) -> None:
    mode = env.metadata.get("autoreset_mode")
    if mode != gymnasium.vector.AutoresetMode.SAME_STEP:
        raise ValueError(
            f"TRPO needs a vector env with autoreset_mode=AutoresetMode.SAME_STEP, got {mode}: "
            "with NEXT_STEP the step after an episode end is a reset, not a transition "
            "(use vdtutorial.rollout.make_vec_env)"
        )
    if steps_per_iter % env.num_envs:
        raise ValueError(f"steps_per_iter={steps_per_iter} is not a multiple of num_envs={env.num_envs}")


def iteration_seeds(seed: int, iteration: int, num_envs: int) -> tuple[list[int], int]:
    """One iteration's environment reset seeds, and the seed of the generator for its action noise (and its Fisher
    subsample): each iteration starts afresh from both, so no generator state outlives an iteration."""
    state = np.random.SeedSequence([seed, iteration]).generate_state(num_envs + 1)
    return [int(s) for s in state[:-1]], int(state[-1])


def _time_major(steps: list[np.ndarray]) -> np.ndarray:
    """T observation batches of shape (N, ...) -> one batch of shape (T * N, ...), time-major."""
    stacked = np.stack(steps)
    return stacked.reshape(-1, *stacked.shape[2:])


@dataclass
class Rollout:
    """What running the policy for one batch gave, before any baseline: T steps of N sub-environments."""

    observations: Obs  # (T * N, ...) the observations acted on, time-major
    actions: torch.Tensor  # (T * N, action_dim) the sampled (unclipped) actions
    timesteps: np.ndarray  # (T * N,) step index within the episode
    rewards: np.ndarray  # (T, N)
    dones: np.ndarray  # (T, N) True where an episode ended with the step
    last_obs: Obs  # (N, ...) the observations after the last step (where the batch cut off)
    last_timesteps: np.ndarray  # (N,) their steps within the episode
    episode_returns: list[float]  # undiscounted returns of the episodes that ended in the batch
    successes: int  # how many of those ended with info["is_success"] True
    time_limit_ends: list[tuple]  # (step, env, final observation, its time step) where a time limit struck


def rollout(
    policy: nn.Module,
    env: gymnasium.vector.VectorEnv,
    steps_per_env: int,
    env_seeds: list[int],
    generator: torch.Generator,
    keep_time_limit_ends: bool = False,
) -> Rollout:
    """Step 1: reset ``env`` with ``env_seeds`` and run ``policy`` for ``steps_per_env`` vector steps, one policy
    forward per step, the action noise drawn from ``generator`` and the actions clipped to the action space. An episode
    that ends is reset in the same step; those still running at the end are cut off. ``keep_time_limit_ends`` records
    the episodes that a time limit ended, with their final observations (for ``TRPOConfig.bootstrap_time_limits``)."""
    n, space = env.num_envs, env.single_action_space
    obs, _ = env.reset(seed=env_seeds)
    t = np.zeros(n, dtype=np.int64)  # step within the current episode, per env
    running_return = np.zeros(n)
    observations, actions, timesteps = [], [], []
    rewards, dones = np.zeros((steps_per_env, n)), np.zeros((steps_per_env, n))
    episode_returns, successes, time_limit_ends = [], 0, []
    for k in range(steps_per_env):
        with torch.no_grad():  # one policy forward for all sub-environments
            dist = policy.distribution(obs_to_tensor(obs))
            action = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=generator, dtype=dist.mean.dtype)
        next_obs, reward, terminated, truncated, info = env.step(np.clip(action.numpy(), space.low, space.high))
        done = terminated | truncated
        observations.append(obs)
        actions.append(action)
        timesteps.append(t)
        rewards[k], dones[k] = reward, done
        running_return += reward
        if done.any():
            successes += _successes(info["final_info"], done)
            episode_returns.extend(running_return[done].tolist())
            running_return[done] = 0.0
            if keep_time_limit_ends:
                time_limit_ends += [
                    (k, i, info["final_obs"][i], t[i] + 1) for i in np.flatnonzero(truncated & ~terminated)
                ]
        t = np.where(done, 0, t + 1)
        obs = next_obs  # after an episode end this is already the next episode's first obs
    return Rollout(
        stack_obs(_time_major, observations),
        torch.cat(actions),
        np.concatenate(timesteps),
        rewards,
        dones,
        obs,
        t,
        episode_returns,
        successes,
        time_limit_ends,
    )


def _successes(final_info: dict, done: np.ndarray) -> int:
    """How many of the episodes that ended in this vector step reported ``info["is_success"]`` True."""
    if "is_success" not in final_info:
        return 0
    reported = np.flatnonzero(final_info["_is_success"] & done)
    return sum(bool(final_info["is_success"][i]) for i in reported)
