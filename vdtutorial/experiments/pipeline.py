"""From demonstrations to a policy ready for RL: the pipeline of the experiments, one step per function, in the
order they run (:func:`finetune_policy` runs them all)::

    demos = load_demos(task, demos)                                  # the data set
    policy = pretrained_policy(method, demos, obs_mode, seed, cfg)   # cloned (or its checkpoint read back),
                                                                     # with its start sigma for RL
    policy = ready_for_rl(method, policy)                            # pruned, if the method prunes

A method that does not pre-train starts from :func:`fresh_policy`. What each method does at each step comes
from its entry in :mod:`vdtutorial.methods`; how a checkpoint is named, found and saved is
:mod:`~vdtutorial.experiments.checkpoints`, and how the start sigma is fitted is
:mod:`~vdtutorial.experiments.initial_sigma`. Neither calls back into this module.

Taught in chapter 07.
"""

from __future__ import annotations

import math
from dataclasses import asdict, replace
from pathlib import Path

import gymnasium as gym
import torch

from vdtutorial.demos import SHIPPED_NOISE, Demos, demo_path
from vdtutorial.experiments.checkpoints import (
    checkpoint_path,
    default_config,
    load_checkpoint,
    pretrain_command,
    reusable_checkpoint,
    save_checkpoint,
)
from vdtutorial.experiments.initial_sigma import InitialSigma, set_initial_sigma
from vdtutorial.experiments.paths import runs_dir
from vdtutorial.methods import method as method_entry
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.pretrain import PAPER_SIGMA_OPTION, PretrainConfig, pretrain
from vdtutorial.settings import budget
from vdtutorial.vd import prune_model

#: The meta entries that say which data set a checkpoint was cloned on: (task, samples, Sigma, demonstration
#: seed) for a one-shot set; a set made in rounds (DART's, DAgger's) has no Sigma but a method and its rounds.
DATA_SET_KEYS = ("task", "samples", "noise", "seed", "method", "rounds_done")


def load_demos(task: str, demos: Demos | str | Path | None = None, root: Path | None = None) -> Demos:
    """``demos`` as a data set: itself, loaded from a path, or (None) the task's shipped 8000-sample set
    (Sigma ``SHIPPED_NOISE[task]``) under ``root`` (default ``data/``). The task must match."""
    if isinstance(demos, Demos):
        if demos.meta.get("task") != task:
            raise ValueError(f"demonstrations of task {demos.meta.get('task')!r} given for task {task!r}")
        return demos
    path = demos if demos is not None else demo_path(task, 8000, SHIPPED_NOISE[task], 0, root=root)
    return Demos.load(path, task=task)


def made_in_rounds(meta: dict) -> bool:
    """Whether a data set was made in rounds (DART's, DAgger's): its meta has no hand-set Sigma to name it by."""
    return "noise" not in meta


def pretrained_policy(
    reg: str,
    demos: Demos,
    obs_mode: str = "state",
    seed: int = 0,
    config: PretrainConfig | None = None,
    checkpoints_root: Path | None = None,
    progress: bool = False,
    source: str | Path | None = None,
) -> GaussianPolicy:
    """The policy pre-trained with the method ``reg`` on ``demos`` with ``config`` and ``seed``.

    A checkpoint (:func:`~vdtutorial.experiments.checkpoints.checkpoint_path`) is reused when it was made from the
    same data set (task, samples, Sigma, demonstration seed) with the same pre-training configuration and seed. The
    shipped one in ``data/checkpoints`` is looked at first, read only (not in quick mode, whose budgets never
    match it); then the one under ``checkpoints_root`` (default ``runs/``, ``runs/quick/`` in quick mode).
    If neither matches, the policy is pre-trained now and saved under ``checkpoints_root`` (replacing a
    stale file there). So the experiments never write into ``data/`` unless ``checkpoints_root`` names it.

    The policy is always returned as read back from a checkpoint, so a fresh and a reused pre-training
    hand TRPO exactly the same object (parameters, and every ``requires_grad`` at its default:
    pre-training freezes sigma, the RL phase trains it). It is not pruned yet.
    A non-default ``config.initial_sigma`` is applied on top of the default checkpoint (mu does not
    depend on it; under "spread" a method without a noise model follows the network of the method its entry
    names, ``spread_from``) and saved as a checkpoint of its own (``..._initsigma-OPTION.pt``), so that a
    resumed run does not fit sigma again.

    source: the data set's file, needed for a set made in rounds (:func:`made_in_rounds`: DART's, DAgger's),
    which has no (samples, Sigma) name: its checkpoints are named after the file (``STEM_REG_OBS_seedS.pt``)
    under ``checkpoints_root`` only (none is shipped)."""
    cfg = replace(config or default_config(reg, obs_mode), reg=reg, obs_mode=obs_mode)
    meta = demos.meta
    if made_in_rounds(meta) and source is None:
        raise ValueError(
            "a data set made in rounds (DART's, DAgger's: no Sigma in its meta) is named by its file: "
            "give its path as source"
        )
    data_name = Path(source).stem if made_in_rounds(meta) else None
    root = Path(checkpoints_root) if checkpoints_root is not None else budget(runs_dir(), runs_dir() / "quick")
    names = {
        "initial_sigma": cfg.initial_sigma,
        "kl_divisor": cfg.kl_divisor,
        "data_name": data_name,
        "patience": cfg.patience,
    }
    path = checkpoint_path(meta, reg, obs_mode, seed, root=root, **names)
    shipped = checkpoint_path(meta, reg, obs_mode, seed, **names)
    candidates = [shipped] if budget(True, False) and shipped != path and data_name is None else []
    expected = {**{k: meta[k] for k in DATA_SET_KEYS if k in meta}, **asdict(cfg)}
    policy = reusable_checkpoint([*candidates, path], expected, seed, root, method_entry(reg).label)
    if policy is not None:
        return policy
    made_from = Path(source) if data_name else demo_path(meta["task"], meta["samples"], meta["noise"], meta["seed"])
    if cfg.initial_sigma != PAPER_SIGMA_OPTION:
        base = replace(cfg, initial_sigma=PAPER_SIGMA_OPTION)
        policy = pretrained_policy(reg, demos, obs_mode, seed, base, checkpoints_root, progress, source)
        spread_net = None
        if InitialSigma.parse(cfg.initial_sigma).kind == "spread":
            spread_net = spread_network(reg, demos, obs_mode, seed, base, checkpoints_root, progress, source)
        policy.pretrain_info["initial_sigma"] = set_initial_sigma(policy, demos, cfg, seed, spread_net=spread_net)
        policy.pretrain_info["config"] = asdict(cfg)
    else:
        policy, _ = pretrain(demos, cfg, seed=seed, progress=progress)
    command = pretrain_command(reg, made_from, seed, obs_mode, cfg.initial_sigma)
    save_checkpoint(policy, path, extra={"command": command})
    return load_checkpoint(path)


def spread_network(
    reg: str,
    demos: Demos,
    obs_mode: str,
    seed: int,
    config: PretrainConfig,
    checkpoints_root: Path | None,
    progress: bool,
    source: str | Path | None,
) -> torch.nn.Module | None:
    """Under the start sigma "spread", the mean network whose predictive spread the method ``reg`` follows: that
    of the method its entry names (``spread_from``), pre-trained alike (the same data, seed and settings, with
    the default L2 coefficient, which is no setting of another method's); None when it follows its own."""
    follows = method_entry(reg).spread_from
    if follows is None or follows == reg:
        return None
    like = replace(config, reg=follows, l2=PretrainConfig.l2)
    return pretrained_policy(follows, demos, obs_mode, seed, like, checkpoints_root, progress, source).mu


def fresh_policy(env: gym.Env | gym.vector.VectorEnv, seed: int, config: PretrainConfig) -> GaussianPolicy:
    """The network a method that does not pre-train starts RL from: fresh for ``env``'s spaces (one env or a vector
    env), seeded with ``seed``, sigma fixed at ``config.initial_sigma``'s value (a fit has no data to fit on)."""
    torch.manual_seed(seed)
    space = getattr(env, "single_observation_space", env.observation_space)
    actions = getattr(env, "single_action_space", env.action_space)
    return make_policy(
        space,
        actions.shape[0],
        variational=method_entry(config.reg).variational,
        init_std=InitialSigma.parse(config.initial_sigma).value,
    )


def ready_for_rl(reg: str, policy: GaussianPolicy) -> GaussianPolicy:
    """The last step before RL: pruned where log alpha > 3 if the method prunes (Section IV-A: pruned weights are
    exact zeros that TRPO never moves). A variational network that does not prune is frozen alike (alphas fixed, no
    weight noise in RL) with every weight of mu kept, and its sigma network as the pruning method's, whose start
    sigma it shares. A plain network is returned as it is."""
    entry = method_entry(reg)
    if entry.prunes:
        return policy.prune_()
    if entry.variational:
        prune_model(policy.sigma)
        prune_model(policy.mu, threshold=math.inf)
    return policy


def finetune_policy(
    method: str,
    env: gym.Env | gym.vector.VectorEnv,
    demos: Demos | None = None,
    obs_mode: str = "state",
    seed: int = 0,
    config: PretrainConfig | None = None,
    *,
    checkpoints_root: Path | None = None,
    progress: bool = False,
    resumed: bool = False,
    source: str | Path | None = None,
) -> GaussianPolicy:
    """The policy RL starts from, for ``method`` on ``env``: the steps of the module docstring, "in the order they run".

    A method that pre-trains: the policy pre-trained on ``demos`` with ``config`` (:func:`pretrained_policy`)
    with its start sigma ``config.initial_sigma`` (the sigma study's choice by default), made ready for RL
    (:func:`ready_for_rl`); for a method whose entry names another's network (``network_of``), that method's
    checkpoint. A method that does not: :func:`fresh_policy` for ``env``.
    ``resumed``: the run continues from a saved state that holds every parameter, so the network is built
    from the default checkpoint without fitting the start sigma again (minutes for an image policy) only
    to be overwritten.
    ``source``: the data set's file, which names a set made in rounds (DART's, DAgger's; see
    :func:`pretrained_policy`).
    """
    entry = method_entry(method)
    if not entry.finetuned:
        raise ValueError(f"method {method!r} is not fine-tuned by RL")
    cfg = replace(config or default_config(method, obs_mode), reg=method)
    if not entry.pretrains:
        return fresh_policy(env, seed, cfg)
    network = replace(cfg, initial_sigma=PAPER_SIGMA_OPTION) if resumed else cfg
    cloned_by = entry.network_of or method  # the checkpoint is that method's: the same network, its start sigma too
    policy = pretrained_policy(cloned_by, demos, obs_mode, seed, network, checkpoints_root, progress, source)
    return ready_for_rl(method, policy)
