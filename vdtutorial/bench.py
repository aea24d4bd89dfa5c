"""Benchmarks a learner waits for, measured on the machine at hand (``python -m vdtutorial bench ...``).

``env``: environment steps per second for each task x observation mode x image size, in one process
and with two worker processes (gymnasium's AsyncVectorEnv), and the IK expert's time per action.
``policy``: network and pre-training cost (:func:`bench_policy`).
``finetune``: TRPO fine-tuning throughput end to end, rollouts + updates (:func:`bench_finetune`).
``trpo``: our TRPO against sb3-contrib's on gymnasium's Pendulum-v1 (:func:`bench_trpo_pendulum`).

Taught in chapter 06b.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.settings import budget
from vdtutorial.trpo import TRPO, TRPOConfig, make_vec_env

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


def _best_time(fn, repeats: int) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _network_times(net, obs, repeats: int) -> tuple[float, float]:
    """Best forward and forward+backward time of ``net`` on a batch."""
    import torch

    def forward():
        with torch.no_grad():
            net(obs)

    def forward_backward():
        net.zero_grad()
        net(obs).square().mean().backward()

    return _best_time(forward, repeats), _best_time(forward_backward, repeats)


def bench_policy(samples: int | None = None, repeats: int | None = None) -> list[dict]:
    """Cost of the mu network for a batch of 200 observations, plain vs sparse VD (training mode, local
    reparameterisation) vs the compacted pruned network, for state and rgbd 128x128 inputs; then one
    pre-training epoch over ``samples`` demonstrations (state inputs; rgbd images re-rendered first).

    The compacted network comes from a VD policy pre-trained on the shipped 8000-sample reach set (the
    shipped checkpoint when present; else trained here for the state network, and for the rgbd network
    the untrained VD network is compacted, which removes almost nothing -- the row says so)."""
    import torch

    from vdtutorial.demos import Demos, demo_path
    from vdtutorial.pretrain import PretrainConfig, checkpoint_path, demo_observations, load_checkpoint, observation_space, pretrain
    from vdtutorial.policy import obs_to_tensor
    from vdtutorial.vd import compact, sparsity_report

    torch.set_num_threads(1)
    samples = samples or budget(8000, 400)
    repeats = repeats or budget(10, 2)
    demos = Demos.load(demo_path("reach", 8000, 0.5, 0))
    rows = []
    print(f"{'obs':6} {'network':26} {'forward ms':>11} {'fwd+bwd ms':>11} {'weights':>9}")
    for obs_mode in ("state", "rgbd"):
        space = observation_space("reach", obs_mode, 128)
        obs = obs_to_tensor(demo_observations(demos, obs_mode, 128, indices=np.arange(200)))
        torch.manual_seed(0)
        plain = make_policy(space, 6, variational=False).mu
        vd = make_policy(space, 6, variational=True).mu.train()
        ckpt = checkpoint_path(demos.meta, "vd", obs_mode, 0)
        if ckpt.exists():
            trained, source = load_checkpoint(ckpt).mu, f"shipped {ckpt.name}"
        elif obs_mode == "state":
            trained = pretrain(demos, PretrainConfig(reg="vd", epochs=budget(150, 3)), progress=False)[0].mu
            source = "pre-trained here"
        else:
            trained, source = make_policy(space, 6, variational=True).mu.eval(), "untrained VD net (no checkpoint)"
        small = compact(trained.eval())
        for name, net in (("plain", plain), ("sparse VD (train mode)", vd), ("compacted pruned", small)):
            fwd, fb = _network_times(net, obs, repeats)
            n_weights = sum(p.numel() for n, p in net.named_parameters() if n.endswith("weight"))
            rows.append({"obs_mode": obs_mode, "network": name, "forward_ms": 1e3 * fwd, "forward_backward_ms": 1e3 * fb, "weights": n_weights})
            print(f"{obs_mode:6} {name:26} {1e3 * fwd:>11.2f} {1e3 * fb:>11.2f} {n_weights:>9d}")
        report = sparsity_report(trained)
        print(f"       compacted from: {source}; {report.weight_fraction:.1%} weights, {report.neuron_fraction:.1%} neurons pruned")
    for obs_mode in ("state", "rgbd"):
        part = Demos(**{k: getattr(demos, k)[:samples] for k in ("joints", "cup", "actions", "episode", "t")},
                     meta={**demos.meta, "samples": samples})
        obs = demo_observations(part, obs_mode, 128)
        for reg in ("l2", "vd"):
            start = time.perf_counter()
            pretrain(part, PretrainConfig(reg=reg, obs_mode=obs_mode, epochs=1, val_fraction=0.0), progress=False, observations=obs)
            seconds = time.perf_counter() - start
            rows.append({"obs_mode": obs_mode, "epoch": reg, "samples": samples, "seconds": seconds})
            print(f"one pre-training epoch, {obs_mode}, {reg}, {samples} samples: {seconds:.2f} s")
    return rows


#: (label, TRPO fisher argument, fvp_subsample) of the fine-tuning benchmark's rows, per observation mode.
FINETUNE_CASES = (
    ("double backward", "double_backward", 1.0),  # the generic product, chapter 06's teaching version
    ("Gauss-Newton", "gauss_newton", 1.0),        # the same matrix, vdtutorial.fisher's cheaper form
    ("Gauss-Newton", "gauss_newton", 0.1),        # the 10% subsample, a control
)


def bench_finetune(iterations: int | None = None, profile: bool = False,
                   device: torch.device | str = "cpu") -> list[dict]:
    """TRPO fine-tuning of the pruned VD reach policy (8000 demonstrations, Sigma = 0.5, seed 0), state
    and rgbd 128 x 128, in one process with one torch thread: seconds per 200-step iteration spent
    collecting (rendering + policy) and updating, env steps per second end to end (wall clock, and per
    second of this process's CPU time, which depends less on other load on the machine), and the mean
    KL and accepted step fraction of the updates. One row per :data:`FINETUNE_CASES` entry: the exact
    Fisher-vector products on the whole batch by double backward and in Gauss-Newton form, then the
    Gauss-Newton form on a 10% subsample. The cases of one observation mode take turns iteration by
    iteration (each with its own policy and the same seeds), so that a change in the machine's load
    affects them alike; the speed-up of the Gauss-Newton form on the whole batch is printed after
    them. One warm-up iteration each, then ``iterations`` timed ones (default 10; quick mode 2).

    A second table splits each case's update into its parts, in CPU seconds per iteration
    (``TRPO.update_split``): the surrogate gradient (with the forward pass at theta_old), the Fisher
    setup, the CG products, the line search and the baseline fit. With ``profile``, the rgbd whole-batch
    Gauss-Newton case then runs ``iterations`` more under the profilers (:func:`print_profile`).

    ``device``: where the updates run (``TRPO(device=...)``; "cuda": a GPU). The rollouts stay on the CPU, so
    the collect column does not change; the update column is wall time with the GPU, and the CPU-time columns
    (steps per CPU second, the update split) count what this process spent, waiting for the GPU included."""
    import torch

    from vdtutorial.demos import Demos, demo_path
    from vdtutorial.experiments import NUM_ENVS, finetune_policy
    from vdtutorial.pretrain import PretrainConfig, checkpoint_path, default_config, load_checkpoint
    from vdtutorial.trpo import TRPO, TRPOConfig, make_vec_env

    iterations = iterations or budget(10, 2)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    demos = Demos.load(demo_path("reach", 8000, 0.5, 0))
    rows = []
    print(f"{'obs':6} {'Fisher product':16} {'fvp_subsample':>13} {'collect s':>10} {'update s':>9} {'steps/s':>8} "
          f"{'steps/cpu s':>11} {'mean KL':>8} {'step fraction':>13}")
    for obs_mode in ("state", "rgbd"):
        env = make_vec_env(ENV_IDS["reach"], NUM_ENVS, obs_mode=obs_mode, image_size=128)
        # the shipped checkpoint with its own settings (any mode), else one pre-trained now with the defaults
        ckpt = checkpoint_path(demos.meta, "vd", obs_mode, 0)
        config = (PretrainConfig(**load_checkpoint(ckpt).pretrain_info["config"]) if ckpt.exists()
                  else default_config("vd", obs_mode))
        source = f"shipped {ckpt.name}" if ckpt.exists() else "pre-trained now (no shipped checkpoint)"
        runs = []
        for label, fisher, fvp_subsample in FINETUNE_CASES:
            torch.manual_seed(0)
            policy = finetune_policy("vd", env, demos, obs_mode, 0, config, checkpoints_root=ckpt.parent.parent)
            algo = TRPO(policy, env, TRPOConfig(fvp_subsample=fvp_subsample), seed=0, fisher=fisher, device=device)
            runs.append((algo, []))
        for i in range(iterations + 1):
            for algo, timed in runs:  # every case collects from the shared env, reset with its own seeds
                cpu = time.process_time()
                row = algo.iterate()
                if i > 0:  # the first iteration warms up
                    timed.append((row, time.process_time() - cpu, algo.update_split))
        for (label, fisher, fvp_subsample), (algo, timed) in zip(FINETUNE_CASES, runs):
            row = {"obs_mode": obs_mode, "fisher": fisher, "fvp_subsample": fvp_subsample, "policy": source,
                   **_finetune_summary(timed, algo.config.steps_per_iter)}
            rows.append(row)
            print(f"{obs_mode:6} {label:16} {fvp_subsample:>13g} {row['collect_s']:>10.3f} {row['update_s']:>9.3f} "
                  f"{row['steps_per_s']:>8.1f} {row['steps_per_cpu_s']:>11.1f} {row['mean_kl']:>8.4f} "
                  f"{row['step_fraction']:>13.3f}", flush=True)
        _print_update_split(rows[-len(FINETUNE_CASES):], [label for label, *_ in FINETUNE_CASES])
        old, new = rows[-len(FINETUNE_CASES):][:2]
        print(f"       whole batch, Gauss-Newton / double backward: {new['steps_per_s'] / old['steps_per_s']:.2f}x env "
              f"steps/s ({new['steps_per_cpu_s'] / old['steps_per_cpu_s']:.2f}x per CPU second), update "
              f"{old['update_s'] / new['update_s']:.2f}x faster")
        print(f"       policy: {source}, pruned; {iterations} iterations of 200 steps after one warm-up, per case; "
              f"updates on {torch.device(device)}")
        if profile and obs_mode == "rgbd":
            print_profile(runs[FINETUNE_CASES.index(("Gauss-Newton", "gauss_newton", 1.0))][0], iterations)
        env.close()
    torch.set_num_threads(threads)
    return rows


def _finetune_summary(timed: list[tuple[dict, float, dict]], steps_per_iter: int) -> dict:
    """One fine-tuning case's columns from its timed iterations, (TRPO log row, CPU seconds, update split)
    each: the mean seconds collecting and updating per iteration, env steps per second of both together and
    per CPU second, the mean KL of the steps, the mean accepted fraction of the full step (0 when rejected),
    and the mean CPU seconds of each part of the update (``split_cpu_s``)."""
    rows = [row for row, *_ in timed]
    collect, update = sum(r["collect_s"] for r in rows), sum(r["update_s"] for r in rows)
    steps = len(rows) * steps_per_iter
    fractions = [0.0 if r["line_search"] == "rejected" else r["line_search"] for r in rows]
    splits = [split for *_, split in timed]
    return {"collect_s": collect / len(rows), "update_s": update / len(rows), "steps_per_s": steps / (collect + update),
            "steps_per_cpu_s": steps / sum(cpu for _, cpu, _ in timed),
            "mean_kl": float(np.mean([r["mean_kl"] for r in rows])), "step_fraction": float(np.mean(fractions)),
            "split_cpu_s": {part: float(np.mean([s[part] for s in splits])) for part in splits[0]}}


def _print_update_split(rows: list[dict], labels: list[str]) -> None:
    """The update's parts per case, CPU seconds per iteration (see :func:`bench_finetune`)."""
    parts = list(rows[0]["split_cpu_s"])
    print(f"       update split, CPU s per iteration: {'':16} {'':>13} " + " ".join(f"{p:>12}" for p in parts))
    for label, row in zip(labels, rows):
        print(f"{row['obs_mode']:6} {label:16} {row['fvp_subsample']:>13g} {'':>35}"
              + " ".join(f"{row['split_cpu_s'][p]:>12.3f}" for p in parts))


def print_profile(algo: TRPO, iterations: int, top: int = 15) -> None:
    """Run ``iterations`` TRPO iterations of ``algo`` under torch's profiler and cProfile and print where
    the time went: the ``top`` torch operators by self CPU time (convolutions, matrix products, copies),
    then the ``top`` Python-level functions by their own time (the renderer, pybullet, the Python code)."""
    import cProfile
    import pstats

    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as torch_profile:
        for _ in range(iterations):
            algo.iterate()
    print(f"\nprofile: {iterations} iterations of the rgbd whole-batch Gauss-Newton case; torch operators")
    print(torch_profile.key_averages().table(sort_by="self_cpu_time_total", row_limit=top))
    python_profile = cProfile.Profile()
    python_profile.enable()
    for _ in range(iterations):
        algo.iterate()
    python_profile.disable()
    print(f"the same, {iterations} more iterations; Python functions by their own time")
    pstats.Stats(python_profile).sort_stats("tottime").print_stats(top)


# ----------------------------------------------------------------------------------------------
# TRPO on a standard task: gymnasium's Pendulum-v1, ours against sb3-contrib's
# ----------------------------------------------------------------------------------------------
def pendulum_policy(env) -> GaussianPolicy:
    """The package's own Gaussian policy (:func:`~vdtutorial.policy.make_policy`, kind ``"mlp"``) for a
    Pendulum-v1 vector env: mu and sigma networks of 64-64 tanh units, sigma a softplus with a floor, starting at
    1.0 (the start of sb3's MlpPolicy, log std 0; its actor is otherwise its own: one state-independent log std,
    orthogonal initialisation). The observation is fed unnormalised: its angular velocity's bound, +-8 rad/s, is
    a clip far wider than a swing's velocities, and dividing by it slowed learning (1e5 steps, seeds 11-13, linear
    baseline: final return -683 normalised, -269 not)."""
    return make_policy(env.single_observation_space, env.single_action_space.shape[0], kind="mlp",
                       init_std=PENDULUM_INIT_STD, normalise=False, scene_hidden=(64, 64))


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
ZOO_PENDULUM_CONFIG = TRPOConfig(steps_per_iter=ZOO_PENDULUM_NUM_ENVS * 1024, gamma=0.9, gae_lambda=0.95, max_kl=0.01,
                                 cg_iters=15, cg_damping=0.1, backtrack_iters=10, backtrack_coeff=0.8, baseline="mlp",
                                 critic_lr=1e-3, critic_epochs=15, critic_batch_size=128, bootstrap_time_limits=True)


def sb3_trpo_kwargs(config: TRPOConfig, num_envs: int) -> dict:
    """sb3-contrib ``TRPO``'s keyword arguments for the settings of ``config`` on ``num_envs``
    sub-environments, value network included (its ``n_critic_updates`` are our critic epochs)."""
    return {"n_steps": config.steps_per_iter // num_envs, "gamma": config.gamma, "gae_lambda": config.gae_lambda,
            "target_kl": config.max_kl, "cg_max_steps": config.cg_iters, "cg_damping": config.cg_damping,
            "line_search_max_iter": config.backtrack_iters, "line_search_shrinking_factor": config.backtrack_coeff,
            "learning_rate": config.critic_lr, "n_critic_updates": config.critic_epochs,
            "batch_size": config.critic_batch_size,
            "policy_kwargs": {"net_arch": {"pi": [64, 64], "vf": list(config.critic_hidden)}}}


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
    PendulumVariant("sb3_same", "(a) sb3-contrib, same settings", PENDULUM_NUM_ENVS,
                    sb3_kwargs=sb3_trpo_kwargs(PENDULUM_CRITIC_CONFIG, PENDULUM_NUM_ENVS)),
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
    env = make_vec_env(lambda: gym.wrappers.RecordEpisodeStatistics(gym.make("Pendulum-v1"), buffer_length=episodes),
                       variant.num_envs)
    torch.manual_seed(seed)
    policy = pendulum_policy(env)
    algo = TRPO(policy, env, variant.config, seed=seed)
    start, cpu_start = time.perf_counter(), time.process_time()  # the training only, as for sb3-contrib
    algo.run(total_steps, progress=False)                          # (building Adam imports torch._dynamo once)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    per_env = [list(e.return_queue) for e in env.envs]
    low, high = env.single_action_space.low, env.single_action_space.high
    algo.close()

    def act(obs):
        with torch.no_grad():
            return np.clip(policy.distribution(torch.as_tensor(obs[None], dtype=torch.float32)).mean[0].numpy(), low, high)

    return {"final_return": _late_mean_return(per_env, variant.num_envs, total_steps),
            "eval_return": _deterministic_return(act, seed), "seconds": seconds, "cpu_seconds": cpu_seconds}


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
    return {"final_return": _late_mean_return(per_env, variant.num_envs, total_steps),
            "eval_return": _deterministic_return(lambda obs: model.predict(obs, deterministic=True)[0], seed),
            "seconds": seconds, "cpu_seconds": cpu_seconds}


def bench_trpo_pendulum(seeds: tuple[int, ...] | None = None, total_steps: int | None = None,
                        with_sb3: bool = True) -> dict[str, dict[str, list[float]]]:
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
    cpu_seconds: the CPU time this process spent on it, which a busy machine inflates less. Defaults: seeds 11, 12, 13 x 1e5
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
            final, evaluation, seconds, cpu = (np.array(results[variant.name][k]) for k in
                                               ("final_return", "eval_return", "seconds", "cpu_seconds"))
            tqdm.write(f"{variant.label:44} {final.mean():8.1f} +- {final.std():5.1f} {evaluation.mean():10.1f} +- "
                       f"{evaluation.std():5.1f} {seconds.mean():11.1f} {cpu.mean():7.1f}")
    print("(c) differs from (b) by gSDE, which our TRPO lacks. Within (a) the remaining differences are the "
          "policy network (ours: the package's mu and sigma networks, sigma a function of the state; sb3: "
          "one log std, orthogonal initialisation), the KL direction (sb3: KL(new || old)), the line search's KL test "
          "(sb3: strict <) and Adam's eps (sb3: 1e-5).")
    torch.set_num_threads(threads)
    return results
