"""One run of the paper's experiments: a pre-trained (or fresh) policy fine-tuned by TRPO, or the IK
expert measured as a reference line. See the package docstring for what a run and a seed are.

Taught in chapter 07.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RecordEpisodeStatistics

from vdtutorial.demos import Demos
from vdtutorial.envs import ENV_IDS, HORIZON
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.evaluation import EPISODE_STEPS, ExpertController, successes_per_episode
from vdtutorial.experiments.initial_sigma import InitialSigma
from vdtutorial.experiments.pipeline import load_demos, made_in_rounds, finetune_policy
from vdtutorial.fast.fisher import gauss_newton_fvp
from vdtutorial.fast.policy import fast_policy
from vdtutorial.methods import method as method_entry
from vdtutorial.policy import GaussianPolicy
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.rollout import make_vec_env
from vdtutorial.runner.resume import (
    check_resumable,
    numerics_stretches,
    numerics_warning,
    read_run_state,
    restore_random_states,
    save_run_state,
)
from vdtutorial.runner.rows import write_csv
from vdtutorial.settings import budget
from vdtutorial.trpo import TRPO, TRPOConfig

#: The paper's fine-tuned methods (the figures' own lists: :data:`~vdtutorial.experiments.figures.FIGURES`).
RL_METHODS = ("vd", "l2", "none")
#: Sub-environments of the vector env: 8 runs of at most 25 steps (HORIZON) fill one 200-step iteration.
NUM_ENVS = EPISODE_STEPS // HORIZON
#: Row column plotted for each task: successes per 200-step episode (reach), cumulative reward (grasp).
METRIC = {"reach": "successes", "grasp": "mean_return"}
#: The control of Fisher-vector products on 10% of each batch (``--fvp-subsample 0.1``): the value of
#: rllab's first optimiser, later changed to the whole batch (``TRPOConfig.fvp_subsample``). Not a default.
SUBSAMPLED_FISHER_CONFIG = TRPOConfig(fvp_subsample=0.1)
#: TRPO iterations between two saved states of a resumable run (2000 env steps at 200 per iteration:
#: a short wait in state mode, a longer one for an image policy with the whole-batch Fisher).
CHECKPOINT_EVERY = 10
#: The meta entries that say which data set a checkpoint was cloned on: (task, samples, Sigma, demonstration
#: seed) for a one-shot set; a set made in rounds (DART's, DAgger's) has no Sigma but a method and its rounds.
DATA_SET_KEYS = ("task", "samples", "noise", "seed", "method", "rounds_done")


def default_trpo_config() -> TRPOConfig:
    """TRPO settings of the experiments, the same for state and image observations: ``TRPOConfig()``, i.e.
    Fisher-vector products on the whole batch, as rllab (which the paper used) has computed them since 2016.
    :data:`SUBSAMPLED_FISHER_CONFIG` is the labelled 10% control."""
    return TRPOConfig()


def default_total_steps() -> int:
    """The RL budget of a run: the paper's 3e5 env steps (quick mode: 2000), looked up when the run starts."""
    return budget(300_000, 2_000)


def default_seeds() -> tuple[int, ...]:
    """The seeds of an experiment: three (quick mode: two), looked up when the experiment starts."""
    return budget((0, 1, 2), (0, 1))


def default_expert_episodes() -> int:
    """200-step episodes measured per seed for the expert's reference line (quick mode: one)."""
    return budget(5, 1)


def run_settings(
    method: str,
    task: str,
    demos_meta: dict | None,
    obs_mode: str,
    seed: int,
    num_envs: int,
    pretrain_config: PretrainConfig,
    trpo_config: TRPOConfig,
    source: str | Path | None = None,
) -> dict:
    """Everything that determines a fine-tuning run's numbers, as plain data: what a saved run state must
    match to be resumed (:mod:`vdtutorial.runner.resume`). The budget is not in it: a run is the same
    run whatever its length, so a finished run can be extended and a shorter request finds it too long.
    A data set made in rounds (:func:`made_in_rounds`) is named by its method, rounds and file (``source``)."""
    settings = {
        "method": method,
        "task": task,
        "obs_mode": obs_mode,
        "seed": int(seed),
        "num_envs": int(num_envs),
        "image_size": int(pretrain_config.image_size),
        "trpo_config": asdict(trpo_config),
    }
    if method_entry(method).pretrains:
        settings["demos"] = (
            {
                "samples": int(demos_meta["samples"]),
                "seed": int(demos_meta["seed"]),
                "method": demos_meta["method"],
                "rounds_done": int(demos_meta["rounds_done"]),
                "file": Path(source).name,
            }
            if made_in_rounds(demos_meta)
            else {
                "samples": int(demos_meta["samples"]),
                "noise": float(demos_meta["noise"]),
                "seed": int(demos_meta["seed"]),
            }
        )
        settings["pretrain_config"] = asdict(replace(pretrain_config, reg=method, obs_mode=obs_mode))
    else:  # no demonstrations: only the fixed sigma the run starts from comes from the pre-training config
        settings["init_std"] = InitialSigma.parse(pretrain_config.initial_sigma).value
    return settings


def expert_settings(task: str, seed: int, episodes: int, num_envs: int = NUM_ENVS) -> dict:
    """The settings of an expert-reference run (see :func:`run_settings`)."""
    return {"method": "expert", "task": task, "seed": int(seed), "episodes": int(episodes), "num_envs": int(num_envs)}


def finetune_steps(
    method: str,
    task: str = "reach",
    demos: Demos | str | Path | None = None,
    obs_mode: str = "state",
    seed: int = 0,
    total_steps: int | None = None,
    csv_path: str | Path | None = None,
    *,
    pretrain_config: PretrainConfig | None = None,
    trpo_config: TRPOConfig | None = None,
    num_envs: int = NUM_ENVS,
    checkpoints_root: Path | None = None,
    progress: bool = False,
    state_path: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    device: str = "cpu",
):
    """:func:`finetune` as a generator: it yields after every ``checkpoint_every`` iterations (with no
    ``state_path``: once, at the end) a progress report ``{"iteration": done so far, "iterations": total,
    "env_steps": steps of this chunk}``, and returns ``(policy, rows)`` (``yield from`` gets them).

    state_path: the run's resumable state. If the file exists, the run continues from it -- after
        checking that it was saved with the same settings (:func:`run_settings`; otherwise
        :class:`~vdtutorial.runner.resume.ResumeError`) -- and every chunk saves it again. The rows
        are then those of an uninterrupted run (wall times aside). A resumed pre-trained run needs only the
        default checkpoint (the state holds every parameter, the fitted start sigma included).
    device: where TRPO's updates run (:class:`~vdtutorial.trpo.TRPO`; "cuda": a GPU, whose rows differ from the
        CPU's by floating-point rounding). It is not one of the run's settings; pre-training, when no checkpoint
        matches, stays on the CPU, so that a checkpoint is the same whatever the device.
    """
    entry = method_entry(method)
    if not entry.finetuned:
        raise ValueError(f"method {method!r} is not fine-tuned (the expert is measured by expert_reference)")
    total_steps = default_total_steps() if total_steps is None else total_steps
    cfg = pretrain_config or default_config(method, obs_mode)
    trpo_config = trpo_config or default_trpo_config()
    data = load_demos(task, demos) if entry.pretrains else None
    source = Path(demos) if isinstance(demos, (str, Path)) else None
    settings = run_settings(method, task, data and data.meta, obs_mode, seed, num_envs, cfg, trpo_config, source)
    iterations = math.ceil(total_steps / trpo_config.steps_per_iter)
    saved = None
    if state_path is not None and Path(state_path).exists():
        saved = read_run_state(state_path)
        check_resumable(state_path, saved, settings, iterations)
        if (warning := numerics_warning(saved)) is not None:
            warnings.warn(f"{state_path}: {warning}", stacklevel=2)
    start = time.perf_counter()
    env = make_vec_env(ENV_IDS[task], num_envs, obs_mode=obs_mode, image_size=cfg.image_size)
    try:
        policy = finetune_policy(
            method,
            env,
            data,
            obs_mode,
            seed,
            cfg,
            checkpoints_root=checkpoints_root,
            progress=progress,
            resumed=saved is not None,
            source=source,
        )
        algo = TRPO(fast_policy(policy), env, trpo_config, seed=seed, fvp=gauss_newton_fvp, device=device)
        if saved is not None:
            algo.restore(saved)
            restore_random_states(saved)
        stretches = numerics_stretches(saved, algo.iteration_index)
        if csv_path is not None:  # TRPO appends: start the file from the rows so far (a stale file would mix runs)
            Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
            Path(csv_path).unlink(missing_ok=True)
            if algo.rows:
                write_csv(Path(csv_path), algo.rows)
        chunk = checkpoint_every if state_path is not None else iterations
        while algo.iteration_index < iterations:
            first = algo.iteration_index
            algo.run(
                min(iterations, first + chunk) * trpo_config.steps_per_iter,
                csv_path=csv_path,
                progress=progress and state_path is None,
            )
            if state_path is not None:
                seconds = (saved or {}).get("seconds", 0.0) + time.perf_counter() - start
                save_run_state(algo.checkpoint(), state_path, settings, seconds, stretches)
            yield {
                "iteration": algo.iteration_index,
                "iterations": iterations,
                "env_steps": (algo.iteration_index - first) * trpo_config.steps_per_iter,
            }
    finally:
        env.close()
    return policy, algo.rows


def finetune(
    method: str,
    task: str = "reach",
    demos: Demos | str | Path | None = None,
    obs_mode: str = "state",
    seed: int = 0,
    total_steps: int | None = None,
    csv_path: str | Path | None = None,
    *,
    pretrain_config: PretrainConfig | None = None,
    trpo_config: TRPOConfig | None = None,
    num_envs: int = NUM_ENVS,
    checkpoints_root: Path | None = None,
    progress: bool = False,
    state_path: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    device: str = "cpu",
) -> tuple[GaussianPolicy, list[dict]]:
    """One run of the RL stage: the policy of ``method`` (a fine-tuned method of :mod:`vdtutorial.methods`: the
    paper's "vd", "l2", "none", or one registered there) trained by TRPO for
    ``total_steps`` env steps (default 3e5) on ``num_envs`` copies of the task (default 8 x 25 = 200 steps
    per iteration). Returns the trained policy and TRPO's log rows; ``csv_path`` (replaced if it exists)
    receives the rows as they come.

    demos: the data set of the pre-training (a :class:`Demos` or a path; default the task's shipped
        8000-sample set); ignored by a method that does not pre-train. A set made in rounds (DART's, DAgger's) is
        given by its path,
        which names its checkpoints and its runs' settings.
    pretrain_config: behavioural-cloning settings (``reg`` and ``obs_mode`` are set from ``method`` and
        ``obs_mode``); its ``image_size`` is also the camera's in the RL environment.
    trpo_config: default :func:`default_trpo_config`.
    checkpoints_root: where pre-trained checkpoints are looked up and saved (see :func:`pretrained_policy`).
    state_path, checkpoint_every: make the run resumable (see :func:`finetune_steps`).
    device: where TRPO's updates run (see :func:`finetune_steps`).
    """
    steps = finetune_steps(
        method,
        task,
        demos,
        obs_mode,
        seed,
        total_steps,
        csv_path,
        pretrain_config=pretrain_config,
        trpo_config=trpo_config,
        num_envs=num_envs,
        checkpoints_root=checkpoints_root,
        progress=progress,
        state_path=state_path,
        checkpoint_every=checkpoint_every,
        device=device,
    )
    while True:
        try:
            next(steps)
        except StopIteration as finished:
            return finished.value


def expert_reference(
    task: str = "reach", seed: int = 0, episodes: int | None = None, num_envs: int = NUM_ENVS
) -> list[dict]:
    """The IK expert's score per 200-step episode, measured as TRPO's iterations count: each episode is
    ``num_envs`` runs of ``200 / num_envs`` steps from a fresh reset (the seeds of episode k derive
    from (seed, k)); trajectories still running at the end are not counted. One row per episode with
    ``successes``, ``failures``, ``episodes`` (trajectories that ended) and ``mean_return`` (their mean
    undiscounted return)."""
    episodes = default_expert_episodes() if episodes is None else episodes
    env = RecordEpisodeStatistics(gym.make(ENV_IDS[task], obs_mode="state"), buffer_length=EPISODE_STEPS)
    controller = ExpertController(env)
    rows = []
    for k in range(episodes):
        env.return_queue.clear()
        row = {"episode": k, "successes": 0, "failures": 0, "episodes": 0}
        for reset_seed in np.random.SeedSequence([seed, k]).generate_state(num_envs):
            counts = successes_per_episode(env, controller, steps=EPISODE_STEPS // num_envs, seed=int(reset_seed))
            row["successes"] += counts["successes"]
            row["failures"] += counts["failures"]
            row["episodes"] += counts["trajectories"]
        row["mean_return"] = float(np.mean(env.return_queue)) if env.return_queue else math.nan
        rows.append(row)
    env.close()
    return rows
