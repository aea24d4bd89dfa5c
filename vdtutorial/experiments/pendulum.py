"""TRPO on a standard task, ours against a peer's: gymnasium's Pendulum-v1, our TRPO with the paper's
settings, with sb3-contrib's settings, and sb3-contrib's own TRPO with its defaults and with RL Zoo's tuned
entry (``python -m vdtutorial bench trpo``).

Taught in chapter 06b and appendix A2: chapter 06b trains on Pendulum-v1 with :data:`PENDULUM_CONFIG`, appendix
A2 describes the benchmark.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from vdtutorial.beyond.value_baseline import value_baseline
from vdtutorial.fast.fisher import gauss_newton_fvp
from vdtutorial.fast.policy import fast_policy
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.rollout import make_vec_env
from vdtutorial.settings import budget
from vdtutorial.trpo import TRPO, TRPOConfig


def pendulum_policy(env) -> GaussianPolicy:
    """The package's own Gaussian policy (:func:`~vdtutorial.policy.make_policy`, kind ``"mlp"``) for a
    Pendulum-v1 vector env: mu and sigma networks of 64-64 tanh units, sigma a softplus with a floor, starting at
    1.0 (the start of sb3's MlpPolicy, log std 0; its actor is otherwise its own: one state-independent log std,
    orthogonal initialisation). The observation is fed unnormalised: its angular velocity's bound, +-8 rad/s, is
    a clip far wider than a swing's velocities, and dividing by it slowed learning (1e5 steps, seeds 11-13, linear
    baseline: final return -683 normalised, -269 not)."""
    return make_policy(
        env.single_observation_space,
        env.single_action_space.shape[0],
        kind="mlp",
        init_std=PENDULUM_INIT_STD,
        normalise=False,
        scene_hidden=(64, 64),
    )


#: The policy's starting sigma on Pendulum-v1 (actions in [-2, 2]): sb3's default start, exp(0).
PENDULUM_INIT_STD = 1.0

#: Pendulum-v1 never terminates; its time limit ends every episode after exactly this many steps.
PENDULUM_EPISODE_STEPS = 200

#: Our defaults (rllab's linear baseline, no bootstrapping at time limits) except the batch: 1600
#: steps on 8 sub-environments hold exactly one whole episode per sub-environment.
PENDULUM_CONFIG = TRPOConfig(steps_per_iter=1600)
PENDULUM_NUM_ENVS = 8

#: (a) The same with a value network and bootstrapping at time limits, as sb3-contrib does: both
#: implementations then run with these numbers (critic minibatches of 160 so that they divide the batch).
PENDULUM_CRITIC_CONFIG = replace(PENDULUM_CONFIG, baseline="mlp", critic_batch_size=160, bootstrap_time_limits=True)

#: (b) RL Zoo's tuned Pendulum-v1 entry for sb3-contrib's TRPO (rl-baselines3-zoo, hyperparams/trpo.yml),
#: on 2 sub-environments; sb3-contrib's defaults for everything else.
ZOO_PENDULUM_SB3 = {"n_steps": 1024, "gamma": 0.9, "n_critic_updates": 15, "use_sde": True, "sde_sample_freq": 4}
ZOO_PENDULUM_NUM_ENVS = 2

#: (c) The same settings for our TRPO: the Zoo's, and sb3-contrib's defaults for the rest (lambda 0.95,
#: KL bound 0.01, 15 CG iterations with damping 0.1, a line search shrinking by 0.8 up to 10 times, a
#: 64-64 value network trained at lr 1e-3 in minibatches of 128). gSDE (``use_sde``: exploration noise
#: that is a function of the state, resampled every 4 steps) has no counterpart here: our policy keeps
#: independent Gaussian noise per step.
ZOO_PENDULUM_CONFIG = TRPOConfig(
    steps_per_iter=ZOO_PENDULUM_NUM_ENVS * 1024,
    gamma=0.9,
    gae_lambda=0.95,
    max_kl=0.01,
    cg_iters=15,
    cg_damping=0.1,
    backtrack_iters=10,
    backtrack_coeff=0.8,
    baseline="mlp",
    critic_lr=1e-3,
    critic_epochs=15,
    critic_batch_size=128,
    bootstrap_time_limits=True,
)


def sb3_trpo_kwargs(config: TRPOConfig, num_envs: int) -> dict:
    """sb3-contrib ``TRPO``'s keyword arguments for the settings of ``config`` on ``num_envs``
    sub-environments, value network included (its ``n_critic_updates`` are our critic epochs)."""
    return {
        "n_steps": config.steps_per_iter // num_envs,
        "gamma": config.gamma,
        "gae_lambda": config.gae_lambda,
        "target_kl": config.max_kl,
        "cg_max_steps": config.cg_iters,
        "cg_damping": config.cg_damping,
        "line_search_max_iter": config.backtrack_iters,
        "line_search_shrinking_factor": config.backtrack_coeff,
        "learning_rate": config.critic_lr,
        "n_critic_updates": config.critic_epochs,
        "batch_size": config.critic_batch_size,
        "policy_kwargs": {"net_arch": {"pi": [64, 64], "vf": list(config.critic_hidden)}},
    }


@dataclass(frozen=True)
class PendulumVariant:
    """One row of the Pendulum benchmark: our TRPO with ``config`` or sb3-contrib's with ``sb3_kwargs``."""

    name: str
    label: str
    num_envs: int
    config: TRPOConfig | None = None
    sb3_kwargs: dict | None = None


PENDULUM_VARIANTS = (
    PendulumVariant("ours_linear", "ours, linear baseline (the paper's setting)", PENDULUM_NUM_ENVS, PENDULUM_CONFIG),
    PendulumVariant("ours_same", "(a) ours, value network, same settings", PENDULUM_NUM_ENVS, PENDULUM_CRITIC_CONFIG),
    PendulumVariant(
        "sb3_same",
        "(a) sb3-contrib, same settings",
        PENDULUM_NUM_ENVS,
        sb3_kwargs=sb3_trpo_kwargs(PENDULUM_CRITIC_CONFIG, PENDULUM_NUM_ENVS),
    ),
    PendulumVariant("sb3_zoo", "(b) sb3-contrib, RL Zoo tuned", ZOO_PENDULUM_NUM_ENVS, sb3_kwargs=ZOO_PENDULUM_SB3),
    PendulumVariant("ours_zoo", "(c) ours, RL Zoo tuned, no gSDE", ZOO_PENDULUM_NUM_ENVS, ZOO_PENDULUM_CONFIG),
)


def _late_mean_return(per_env_returns: list[list[float]], num_envs: int, total_steps: int) -> float:
    """Mean return of the episodes that ended in the last 10% of ``total_steps``. The sub-environments
    step in lock-step and every episode lasts 200 steps, so the k-th episode (k = 1, 2, ...) of each
    ends at global step 200 * num_envs * k."""
    ends = np.concatenate([PENDULUM_EPISODE_STEPS * num_envs * np.arange(1, len(r) + 1) for r in per_env_returns])
    returns = np.concatenate([np.asarray(r, dtype=float) for r in per_env_returns])
    return float(np.mean(returns[ends > 0.9 * total_steps]))


def _deterministic_return(act, seed: int, episodes: int = 10) -> float:
    """Mean return of ``episodes`` Pendulum-v1 episodes under ``act`` (observation -> action, no
    exploration noise), each reset from a seed derived from the run's ``seed``: every variant of a
    seed is evaluated on the same starting states."""
    env = gym.make("Pendulum-v1")
    total = 0.0
    for k in range(episodes):
        obs, _ = env.reset(seed=int(np.random.SeedSequence([seed, k], spawn_key=(2,)).generate_state(1)[0]))
        done = False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(act(obs))
            total += float(reward)
            done = terminated or truncated
    env.close()
    return total / episodes


def _ours_pendulum(variant: PendulumVariant, seed: int, total_steps: int) -> dict:
    episodes = total_steps // PENDULUM_EPISODE_STEPS + 2  # per sub-environment, with room to spare
    env = make_vec_env(
        lambda: gym.wrappers.RecordEpisodeStatistics(gym.make("Pendulum-v1"), buffer_length=episodes), variant.num_envs
    )
    torch.manual_seed(seed)
    policy = pendulum_policy(env)
    network = value_baseline(variant.config, env, seed) if variant.config.baseline == "mlp" else None
    algo = TRPO(fast_policy(policy), env, variant.config, seed=seed, baseline=network, fvp=gauss_newton_fvp)
    start, cpu_start = time.perf_counter(), time.process_time()  # the training only, as for sb3-contrib
    algo.run(total_steps, progress=False)  # (building Adam imports torch._dynamo once)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    per_env = [list(e.return_queue) for e in env.envs]
    low, high = env.single_action_space.low, env.single_action_space.high
    algo.close()

    def act(obs):
        with torch.no_grad():
            return np.clip(
                policy.distribution(torch.as_tensor(obs[None], dtype=torch.float32)).mean[0].numpy(), low, high
            )

    return {
        "final_return": _late_mean_return(per_env, variant.num_envs, total_steps),
        "eval_return": _deterministic_return(act, seed),
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
    }


def _sb3_pendulum(variant: PendulumVariant, seed: int, total_steps: int) -> dict:
    from sb3_contrib import TRPO as SB3TRPO
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    env = sb3_make_vec_env("Pendulum-v1", n_envs=variant.num_envs, seed=seed)
    model = SB3TRPO("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **variant.sb3_kwargs)
    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(total_steps)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    per_env = env.env_method("get_episode_rewards")
    env.close()
    return {
        "final_return": _late_mean_return(per_env, variant.num_envs, total_steps),
        "eval_return": _deterministic_return(lambda obs: model.predict(obs, deterministic=True)[0], seed),
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
    }


def bench_trpo_pendulum(
    seeds: tuple[int, ...] | None = None, total_steps: int | None = None, with_sb3: bool = True
) -> dict[str, dict[str, list[float]]]:
    """Train every :data:`PENDULUM_VARIANTS` row on Pendulum-v1 for ``total_steps`` steps per seed, on
    the same seeds, one torch thread: our TRPO with the paper's linear baseline; (a) ours and
    sb3-contrib's with identical settings, value network and time-limit bootstrapping included; (b)
    sb3-contrib with RL Zoo's tuned settings; (c) ours with those settings, without gSDE (which our
    TRPO does not have). Each package trains its own policy (ours: :func:`pendulum_policy`; sb3-contrib: its
    ``MlpPolicy``). sb3-contrib's rows are skipped if it is not installed or ``with_sb3`` is False.

    Returns ``{variant name: {"final_return": [...], "eval_return": [...], "seconds": [...],
    "cpu_seconds": [...]}}``, one entry per seed, and prints the table. final_return: mean return of
    the training episodes that ended in the last 10% of the steps; eval_return: mean return of 10
    episodes with the mean action (no exploration), from the same starting states for every variant
    (higher returns are better; a random policy gets about -1200); seconds: wall time of the training;
    cpu_seconds: the CPU time this process spent on it, which a busy machine inflates less. Defaults: seeds 11, 12,
    13 x 1e5
    steps (quick mode: seed 11 x 4096 steps)."""
    seeds = tuple(seeds) if seeds is not None else budget((11, 12, 13), (11,))
    total_steps = total_steps if total_steps is not None else budget(100_000, 4_096)
    variants = [v for v in PENDULUM_VARIANTS if v.config is not None]
    if with_sb3:
        try:
            import sb3_contrib  # noqa: F401

            variants = list(PENDULUM_VARIANTS)
        except ImportError:
            print("sb3-contrib is not installed (pip install -e '.[bench]'): benchmarking our TRPO only")
    results, threads = {}, torch.get_num_threads()
    torch.set_num_threads(1)  # every run on one core: comparable, and leaves the other core free
    print(f"Pendulum-v1, {total_steps} steps per run, seeds {list(seeds)}; mean +- std over the seeds")
    print(f"{'variant':44} {'final return':>16} {'deterministic eval':>19} {'s per seed':>11} {'CPU s':>7}")
    with tqdm(total=len(variants) * len(seeds), desc="Pendulum runs", disable=None, leave=False) as bar:
        for variant in variants:
            runner = _ours_pendulum if variant.config is not None else _sb3_pendulum
            runs = []
            for seed in seeds:
                runs.append(runner(variant, seed, total_steps))
                bar.update()
            results[variant.name] = {key: [run[key] for run in runs] for key in runs[0]}
            final, evaluation, seconds, cpu = (
                np.array(results[variant.name][k]) for k in ("final_return", "eval_return", "seconds", "cpu_seconds")
            )
            tqdm.write(
                f"{variant.label:44} {final.mean():8.1f} +- {final.std():5.1f} {evaluation.mean():10.1f} +- "
                f"{evaluation.std():5.1f} {seconds.mean():11.1f} {cpu.mean():7.1f}"
            )
    print(
        "(c) differs from (b) by gSDE, which our TRPO lacks. Within (a) the remaining differences are the "
        "policy network (ours: the package's mu and sigma networks, sigma a function of the state; sb3: "
        "one log std, orthogonal initialisation), the KL direction (sb3: KL(new || old)), the line search's KL test "
        "(sb3: strict <) and Adam's eps (sb3: 1e-5)."
    )
    torch.set_num_threads(threads)
    return results
