"""The experiments' pre-trained checkpoints: the settings they are made with (:func:`default_config`), their
file names (:func:`checkpoint_path`), and saving and loading them with what made them
(:func:`save_checkpoint`, :func:`load_checkpoint`). A checkpoint is the policy's config, its ``state_dict`` and
its ``pretrain_info`` (the config, the seed, the data set's meta and the per-epoch log), in ``torch.save``'s format
compressed with gzip (:mod:`vdtutorial.runner.compressed`; plain ``torch.save`` files still load); loading one
checks it is the policy that was asked for.

Taught in chapter 05.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import vdtutorial
from vdtutorial.demos import DATA_SET_PATTERN, data_set_name, demo_path
from vdtutorial.policy import GaussianPolicy
from vdtutorial.pretrain import PAPER_SIGMA_OPTION, PretrainConfig
from vdtutorial.experiments.paths import recorded_path
from vdtutorial.runner.compressed import load_compressed, save_compressed
from vdtutorial.settings import budget, data_dir

#: Where RL starts in the experiments and the shipped results (``default_config``): option (c), sigma fitted to the
#: VD network's predictive spread, chosen by the rule written before the study (``data/results/sigma_study/RULE.md``)
#: from its 5-seed runs (``sigma_study.json``; the numbers: ``docs/results.md``): the most successes in the first 5
#: TRPO iterations (VD and L2 pooled) among the options that learn at least as well as the fixed 0.3 later on. No
#: pre-training then starts from the fixed 0.3 (its best start in the study). ``PretrainConfig()`` itself keeps the
#: paper's setting, sigma untouched at the network's initial 0.3.
RL_START_SIGMA = "spread"


def rgbd_settings() -> dict:
    """Settings that differ for image policies, looked up when a config is made (the epochs follow quick mode).

    A policy that sees the cup only through the camera must learn image features before they pay off;
    with the state-mode warm-up (30% of the epochs) the KL term prunes the whole image stream of the VD network
    before it is useful, and the held-out error is then worse than L2's; raising beta over all epochs keeps the
    stream alive (the numbers: ``docs/results.md``). Epochs are fewer because an image epoch costs hundreds of
    state epochs on a CPU.
    """
    return {"epochs": budget(40, 2), "beta_warmup": 1.0}


def default_config(reg: str = "vd", obs_mode: str = "state") -> PretrainConfig:
    """The pre-training settings used for shipped checkpoints and experiments, per observation mode, with RL
    starting from ``RL_START_SIGMA``."""
    return PretrainConfig(
        reg=reg, obs_mode=obs_mode, initial_sigma=RL_START_SIGMA, **(rgbd_settings() if obs_mode == "rgbd" else {})
    )


def with_held_out_stop(config: PretrainConfig, cap: int, patience: int) -> PretrainConfig:
    """``config`` stopped on the held-out loss after ``patience`` epochs without a better one, ``cap`` epochs at most,
    with VD's KL warm-up kept at ``config``'s length in epochs (so the first epochs see the same beta schedule as
    the fixed-epoch run): what chapter 05's image comparison and ``pretrain --patience`` use."""
    return replace(config, epochs=cap, beta_warmup=config.beta_warmup * config.epochs / cap, patience=patience)


def pretrain_command(reg: str, demos_path, seed: int, obs_mode: str, initial_sigma: str = PAPER_SIGMA_OPTION) -> str:
    """The command line that makes a checkpoint, as its meta records it (the data set's path relative to the
    folder holding data/, so that a shipped checkpoint names no machine)."""
    sigma = "" if initial_sigma == PAPER_SIGMA_OPTION else f" --sigma {initial_sigma}"
    demos = recorded_path(demos_path)
    return f"python -m vdtutorial pretrain --reg {reg} --demos {demos} --seed {seed} --obs {obs_mode}{sigma}"


#: Fields of ``PretrainConfig`` renamed since files were written: old name -> current name.
RENAMED_FIELDS = {"kl_samples": "kl_divisor"}


def current_field_names(config: dict) -> dict:
    """A recorded ``PretrainConfig`` (a checkpoint's or a results record's) with renamed fields under their
    current names (:data:`RENAMED_FIELDS`), so that files written before a rename still load and compare."""
    return {RENAMED_FIELDS.get(key, key): value for key, value in config.items()}


def checkpoint_path(
    demos_meta: dict,
    reg: str,
    obs_mode: str,
    seed: int = 0,
    root: Path | None = None,
    initial_sigma: str = PAPER_SIGMA_OPTION,
    kl_divisor: int | None = None,
    data_name: str | None = None,
    patience: int | None = None,
) -> Path:
    """Conventional checkpoint name under ``data/checkpoints``; a non-default ``initial_sigma``, ``kl_divisor``
    or ``patience`` is added to the name (``..._seed0_initsigma-demos.pt``, ``..._seed0_kl7200.pt``,
    ``..._seed0_stop10.pt``), so that it never replaces the default checkpoint; so is a data set drawn with another
    seed than the shipped 0 (``TASK_nSAMPLES_sigmaSIGMA_demos1_...``). ``data_name`` names the data set in place of its
    ``TASK_nSAMPLES_sigmaSIGMA``: a set made in rounds (DART's, DAgger's) has no Sigma to be named by."""
    m = demos_meta
    sigma = "" if initial_sigma == PAPER_SIGMA_OPTION else f"_initsigma-{initial_sigma}"
    kl = "" if kl_divisor is None else f"_kl{kl_divisor}"
    stop = "" if patience is None else f"_stop{patience}"
    draw = f"_demos{m['seed']}" if m.get("seed") else ""
    data = data_name or data_set_name(m["task"], m["samples"], m["noise"]) + draw
    return Path(root or data_dir()) / "checkpoints" / f"{data}_{reg}_{obs_mode}_seed{seed}{kl}{stop}{sigma}.pt"


def reusable_checkpoint(
    candidates: list[Path], expected: dict, seed: int, root: Path, label: str
) -> GaussianPolicy | None:
    """The first of ``candidates`` that exists and holds the policy ``expected`` (:func:`load_checkpoint`'s entries)
    pre-trained with ``seed``; None if none does. A file that is another pre-training is named in one plain line:
    the last candidate, under ``root``, will be replaced; an earlier one (the shipped checkpoint beside a run at a
    budget of its own, the usual case) is progress, the method ``label`` pre-trained into ``root``."""
    for candidate in candidates:
        if not candidate.exists():
            continue
        try:
            policy = load_checkpoint(candidate, **expected)
            if policy.pretrain_info.get("seed") == seed:
                return policy
            reason = f"seed={policy.pretrain_info.get('seed')!r}, expected {seed!r}"
        except CheckpointError as exc:
            reason = exc.difference or str(exc)
        if candidate == candidates[-1]:
            print(
                f"checkpoint {recorded_path(candidate)} is another pre-training ({reason}): pre-training again to "
                "replace it",
                flush=True,
            )
        else:
            print(
                f"pre-training {label}, seed {seed}, into {recorded_path(root)} (the shipped "
                f"{recorded_path(candidate)} has other settings: {reason})",
                flush=True,
            )
    return None


def save_checkpoint(policy: GaussianPolicy, path, extra: dict | None = None) -> Path:
    """``state_dict`` plus the policy's config and how it was made; written whole and gzip-compressed
    (:func:`~vdtutorial.runner.compressed.save_compressed`: two workers may make the same checkpoint)."""
    meta = {"vdtutorial": vdtutorial.__version__, **getattr(policy, "pretrain_info", {}), **(extra or {})}
    return save_compressed({"config": policy.config, "state_dict": policy.state_dict(), "meta": meta}, path)


#: The conventional file name of :func:`checkpoint_path`, read back to fill in a make-it hint.
_NAME = re.compile(
    DATA_SET_PATTERN + r"(?:_demos(?P<draw>\d+))?_(?P<reg>\w+?)_(?P<obs>state|rgbd)_seed(?P<seed>\d+)\.pt"
)


def _make_hint(path: Path) -> str:
    """The command that makes the checkpoint ``path``, with the real values when the name is conventional."""
    match = _NAME.fullmatch(path.name)
    if not match:
        return (
            "Make it with: python -m vdtutorial pretrain --reg METHOD --demos FILE --seed SEED --obs {state,rgbd} "
            f"--out {path}"
        )
    demos = demo_path(match["task"], int(match["samples"]), float(match["noise"]), int(match["draw"] or 0))
    return f"Make it with: {pretrain_command(match['reg'], demos, int(match['seed']), match['obs'])} --out {path}"


class CheckpointError(ValueError):
    """A checkpoint is missing, unreadable, or not the policy that was asked for. ``difference``: for a
    checkpoint that is readable but another policy, what differs (``epochs=150, expected 60``), alone."""

    def __init__(self, message: str, difference: str | None = None):
        super().__init__(message)
        self.difference = difference


def load_checkpoint(path, **expected) -> GaussianPolicy:
    """Rebuild a policy from a checkpoint (``weights_only=True``: plain tensors and containers only).

    ``expected`` entries are checked against the policy config (e.g. ``kind="state"``,
    ``variational=True``) or the checkpoint's meta (e.g. ``task``); a mismatch raises
    :class:`CheckpointError` naming the file and what differs."""
    path = Path(path)
    fix = _make_hint(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist. {fix}")
    try:
        blob = load_compressed(path)
        config, state, meta = blob["config"], blob["state_dict"], blob.get("meta", {})
    except Exception as exc:  # torch raises several types for a damaged or foreign file
        raise CheckpointError(f"checkpoint {path} is corrupt or not a vdtutorial checkpoint ({exc}). {fix}") from exc
    if "config" in meta:
        meta = {**meta, "config": current_field_names(meta["config"])}
    # checkpoints made before ``initial_sigma`` existed started RL from the fixed default
    where = {"initial_sigma": PAPER_SIGMA_OPTION, **meta.get("demos", {}), **meta.get("config", {}), **config}
    for key, want in expected.items():
        if where.get(key) != want:
            difference = f"{key}={where.get(key)!r}, expected {want!r}"
            raise CheckpointError(f"checkpoint {path} has {difference}. {meta.get('command', fix)}", difference)
    policy = GaussianPolicy.from_config(config)
    try:
        policy.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(f"checkpoint {path} does not fit its own config ({exc}). {fix}") from exc
    policy.eval()
    policy.pretrain_info = meta
    return policy
