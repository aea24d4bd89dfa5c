"""One run of the paper's experiments: a pre-trained (or fresh) policy fine-tuned by TRPO, or the IK
expert measured as a reference line. See the package docstring for what a run and a seed are."""
from __future__ import annotations

import math
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers import RecordEpisodeStatistics

from vdtutorial.demos import Demos, demo_path
from vdtutorial.envs import ENV_IDS, HORIZON
from vdtutorial.evaluation import EPISODE_STEPS, ExpertController, successes_per_episode
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.pretrain import (CheckpointError, PretrainConfig, checkpoint_path, default_config, load_checkpoint,
                                 pretrain, pretrain_command, save_checkpoint)
from vdtutorial.settings import DATA_DIR, budget
from vdtutorial.trpo import TRPO, TRPOConfig, make_vec_env

RL_METHODS = ("vd", "l2", "none")
METHODS = RL_METHODS + ("expert",)
METHOD_LABELS = {"vd": "VD", "l2": "L2", "none": "no pre-training", "expert": "IK expert"}
#: Sub-environments of the vector env: 8 x 25 steps = one 200-step iteration (see the module docstring).
NUM_ENVS = EPISODE_STEPS // HORIZON
#: Row column plotted for each task: successes per 200-step episode (reach), cumulative reward (grasp).
METRIC = {"reach": "successes", "grasp": "mean_return"}
#: 200-step episodes measured per seed for the expert's reference line.
EXPERT_EPISODES = budget(5, 1)
#: The paper's RL budget, 3e5 env steps, and the quick one.
TOTAL_STEPS = budget(300_000, 2_000)
SEEDS = budget((0, 1, 2), (0, 1))
#: TRPO for image policies: Fisher-vector products on 10% of each batch, as in rllab (which the paper
#: used) -- they dominate the update of the convolutional networks (see ``TRPOConfig.fvp_subsample``).
IMAGE_TRPO_CONFIG = TRPOConfig(fvp_subsample=0.1)
#: Quick-mode results and ``reproduce_quick``'s default folder: ``runs/`` beside ``data/``, not shipped.
RUNS_DIR = DATA_DIR.parent / "runs"



def default_trpo_config(obs_mode: str) -> TRPOConfig:
    """TRPO settings of the experiments: :data:`IMAGE_TRPO_CONFIG` for "rgbd", ``TRPOConfig()`` otherwise."""
    return IMAGE_TRPO_CONFIG if obs_mode == "rgbd" else TRPOConfig()


def load_demos(task: str, demos: Demos | str | Path | None = None, root: Path | None = None) -> Demos:
    """``demos`` as a data set: itself, loaded from a path, or (None) the task's shipped 8000-sample,
    Sigma = 0.5 set under ``root`` (default ``data/``). The task must match."""
    if isinstance(demos, Demos):
        if demos.meta.get("task") != task:
            raise ValueError(f"demonstrations of task {demos.meta.get('task')!r} given for task {task!r}")
        return demos
    return Demos.load(demos if demos is not None else demo_path(task, 8000, 0.5, 0, root=root), task=task)


def pretrained_policy(reg: str, demos: Demos, obs_mode: str = "state", seed: int = 0,
                      config: PretrainConfig | None = None, checkpoints_root: Path | None = None,
                      progress: bool = False) -> GaussianPolicy:
    """The policy pre-trained with ``reg`` ("vd" or "l2") on ``demos``: loaded from its checkpoint
    (``pretrain.checkpoint_path`` under ``checkpoints_root``, default ``data/``, or ``runs/quick/`` in quick
    mode so that quick runs never replace shipped checkpoints) when that file was made
    from the same data set (task, samples, Sigma, demonstration seed) with the same pre-training
    configuration and seed; otherwise pre-trained now and saved there (replacing a stale file).

    The policy is always returned as read back from the checkpoint, so a fresh and a reused
    pre-training hand TRPO exactly the same object (parameters, and every ``requires_grad`` at its
    default: pre-training freezes sigma, the RL phase trains it). It is not pruned yet."""
    cfg = replace(config or default_config(reg, obs_mode), reg=reg, obs_mode=obs_mode)
    meta = demos.meta
    if checkpoints_root is None:  # quick mode never replaces the shipped full-scale checkpoints in data/
        checkpoints_root = budget(None, RUNS_DIR / "quick")
    path = checkpoint_path(meta, reg, obs_mode, seed, root=checkpoints_root)
    expected = {**{k: meta[k] for k in ("task", "samples", "noise", "seed")}, **asdict(cfg)}
    if path.exists():
        try:
            policy = load_checkpoint(path, **expected)
            if policy.pretrain_info.get("seed") == seed:
                return policy
            reason = f"checkpoint {path} was pre-trained with seed {policy.pretrain_info.get('seed')}, not {seed}"
        except CheckpointError as exc:
            reason = str(exc)
        warnings.warn(f"{reason}: pre-training again and replacing it", stacklevel=2)
    policy, _ = pretrain(demos, cfg, seed=seed, progress=progress)
    source = demo_path(meta["task"], meta["samples"], meta["noise"], meta["seed"])
    save_checkpoint(policy, path, extra={"command": pretrain_command(reg, source, seed, obs_mode)})
    return load_checkpoint(path)


def finetune(method: str, task: str = "reach", demos: Demos | str | Path | None = None, obs_mode: str = "state",
             seed: int = 0, total_steps: int | None = None, csv_path: str | Path | None = None, *,
             pretrain_config: PretrainConfig | None = None, trpo_config: TRPOConfig | None = None,
             num_envs: int = NUM_ENVS, checkpoints_root: Path | None = None,
             progress: bool = False) -> tuple[GaussianPolicy, list[dict]]:
    """One run of the RL stage: the policy of ``method`` ("vd", "l2" or "none") trained by TRPO for
    ``total_steps`` env steps (default 3e5) on ``num_envs`` copies of the task (default 8 x 25 = 200 steps
    per iteration). Returns the trained policy and TRPO's log rows; ``csv_path`` (replaced if it exists)
    receives the rows as they come.

    demos: the data set of the pre-training (a :class:`Demos` or a path; default the shipped 8000-sample,
        Sigma = 0.5 set); ignored by "none".
    pretrain_config: behavioural-cloning settings (``reg`` and ``obs_mode`` are set from ``method`` and
        ``obs_mode``); its ``image_size`` is also the camera's in the RL environment.
    trpo_config: default :func:`default_trpo_config` of ``obs_mode``.
    checkpoints_root: where pre-trained checkpoints are looked up and saved (see :func:`pretrained_policy`).
    """
    if method not in RL_METHODS:
        raise ValueError(f"method must be one of {RL_METHODS} (the expert is measured by expert_reference), "
                         f"got {method!r}")
    total_steps = TOTAL_STEPS if total_steps is None else total_steps
    cfg = pretrain_config or default_config(method if method != "none" else "l2", obs_mode)
    env = make_vec_env(ENV_IDS[task], num_envs, obs_mode=obs_mode, image_size=cfg.image_size)
    try:
        if method == "none":
            torch.manual_seed(seed)
            policy = make_policy(env.single_observation_space, env.single_action_space.shape[0], variational=False)
        else:
            policy = pretrained_policy(method, load_demos(task, demos), obs_mode, seed, cfg, checkpoints_root,
                                       progress)
            if method == "vd":
                policy.prune_()
        if csv_path is not None:
            Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
            Path(csv_path).unlink(missing_ok=True)  # TRPO appends: a stale file would mix two runs
        algo = TRPO(policy, env, trpo_config or default_trpo_config(obs_mode), seed=seed)
        rows = algo.run(total_steps, csv_path=csv_path, progress=progress)
    finally:
        env.close()
    return policy, rows


def expert_reference(task: str = "reach", seed: int = 0, episodes: int | None = None,
                     num_envs: int = NUM_ENVS) -> list[dict]:
    """The IK expert's score per 200-step episode, measured as TRPO's iterations count: each episode is
    ``num_envs`` runs of ``200 / num_envs`` steps from a fresh reset (the seeds of episode k derive
    from (seed, k)); trajectories still running at the end are not counted. One row per episode with
    ``successes``, ``failures``, ``episodes`` (trajectories that ended) and ``mean_return`` (their mean
    undiscounted return)."""
    episodes = EXPERT_EPISODES if episodes is None else episodes
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

