"""Behavioural cloning of the IK expert: the pre-training phase of Section IV (Fig. 1, top).

Both regularisers fit the same Gaussian policy pi(a|s) = N(mu(s), sigma(s)) to the data set D of eq. 8
by maximising the log-likelihood of the expert's actions. Only ``mu`` is trained; ``sigma`` keeps its
initial parameters (the paper: "only the parameters of mu are trained in this stage, while those of
sigma remain fixed"), so the likelihood is a weighted squared error whose weights sigma(s)^-2 come
from the untrained sigma network.

``reg="vd"`` -- sparse variational dropout. ``mu`` has SVDO layers and the loss is the negative ELBO of
eqs. 1-3 divided by N (dividing by the data set size keeps the loss on the scale of one sample and
leaves its optimum unchanged):

    loss = - (1/M) sum_m log N(a_m | mu(s_m), sigma(s_m))  +  beta * KL(q(W) || p(W)) / N

with the local reparameterisation trick inside the SVDO layers (eq. 4) and Molchanov's approximation of
the KL to the log-uniform prior. ``beta`` warms up linearly from 0 to 1 over the first
``beta_warmup`` fraction of the epochs: early on the data term shapes the weights, and the KL, which
pushes every weight towards being dropped, comes in gradually (without it many weights are pruned
before the network has learnt anything).

``reg="l2"`` -- the baseline: ``mu`` has plain layers and the loss adds ``l2 * sum(W^2)`` over the
weights of ``mu`` (weight decay; biases excluded).

Taught in chapter 05.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

import vdtutorial
from vdtutorial.demos import DATA_SET_PATTERN, Demos, data_set_name, demo_path
from vdtutorial.envs import ENV_IDS
from vdtutorial.beyond.initial_sigma import IMAGE_FIT_STATES, InitialSigma, apply_initial_sigma
from vdtutorial.policy import GaussianPolicy, make_policy, obs_to_tensor, on_device, torch_device
from vdtutorial.settings import budget, data_dir, recorded_path
from vdtutorial.vd import model_kl, pruned_fraction

REGULARISERS = ("vd", "l2")
#: The paper's fixed initial sigma, 0.3 (option (a)): the default of ``PretrainConfig.initial_sigma`` and the sigma
#: of the checkpoints that experiments cache (mu is the same under every option, which they apply on top)
#: and of checkpoints made before the option existed. Changing the default keeps this constant.
PAPER_INITIAL_SIGMA = InitialSigma().spelling
#: Where RL starts in the experiments and the shipped results (``default_config``): option (c), sigma fitted to the
#: VD network's predictive spread, chosen by the rule written before the study (``data/results/sigma_study/RULE.md``)
#: from its 5-seed runs (``sigma_study.json``): the most successes in the first 5 TRPO iterations (VD and L2 pooled,
#: 37.8 against 34.7 for a fixed 0.05, 31.0 for "demos" and 2.8 for the fixed 0.3) among the options that learn at
#: least as well as the fixed 0.3 later on. No pre-training then starts from the fixed 0.3 (its best start in the
#: study). ``PretrainConfig()`` itself keeps the paper's setting, sigma untouched at the network's initial 0.3.
RL_START_SIGMA = "spread"


@dataclass
class PretrainConfig:
    """Hyperparameters of behavioural cloning.

    epochs: passes over the training split; ``None`` (the default) takes 150, or a few in quick mode, when
        the config is made.
    batch_size: M in eq. 3.
    lr: Adam's step size.
    beta_warmup: fraction of the epochs over which the KL weight beta rises from 0 to 1 (VD only).
    l2: weight-decay coefficient of the L2 baseline (L2 only).
    val_fraction: fraction of the episodes held out.
    image_size: camera image side for ``obs_mode="rgbd"``.
    kl_samples: the N that divides the KL term of the ELBO (VD only). Eq. 3 sums the likelihood over
        the N samples of D and adds the KL once, so per sample the KL weighs 1/N: ``None`` (the
        default) uses this data set's own training-split size, as eq. 3 reads. A fixed number (e.g. the
        largest set's N for every set) keeps the prior's weight per sample the same across data sets of
        different sizes, so that Table I's rows differ only by their data; the paper does not say which
        it used (see ``experiments.table1``).
    initial_sigma: sigma at the start of RL, set after mu is cloned (:mod:`vdtutorial.beyond.initial_sigma`):
        a number (option (a), that fixed sigma), "demos" (b) or "spread" (c). Default: the paper's fixed
        0.3. It does not change mu.
    patience: stop on the held-out loss. ``None`` (the default, the shipped checkpoints' setting): run all
        ``epochs``. A number P: ``epochs`` becomes a cap, and cloning stops once the held-out MSE of the mean
        action has not improved for P epochs; mu is then the best epoch's. For VD the count starts when the KL
        warm-up is over (before it, the objective itself is still changing). The paper does not say how long it
        cloned; this is how issue 32 asks whether our fixed 40 image epochs stopped short.
    """

    reg: str = "vd"
    obs_mode: str = "state"
    epochs: int | None = None
    batch_size: int = 100
    lr: float = 1e-3
    beta_warmup: float = 0.3
    l2: float = 1e-4
    val_fraction: float = 0.1
    image_size: int = 128
    kl_samples: int | None = None
    initial_sigma: str = PAPER_INITIAL_SIGMA
    patience: int | None = None

    def __post_init__(self):
        if self.epochs is None:
            self.epochs = budget(150, 4)
        self.initial_sigma = InitialSigma.parse(self.initial_sigma).spelling
        if self.reg not in REGULARISERS:
            raise ValueError(f"reg must be one of {REGULARISERS}, got {self.reg!r}")
        if self.obs_mode not in ("state", "rgbd"):
            raise ValueError(f"obs_mode must be 'state' or 'rgbd', got {self.obs_mode!r}")
        if self.epochs < 1 or self.batch_size < 1 or not 0 <= self.val_fraction < 1:
            raise ValueError("epochs and batch_size must be >= 1 and val_fraction in [0, 1)")
        if self.kl_samples is not None and self.kl_samples < 1:
            raise ValueError(f"kl_samples must be None or a positive integer, got {self.kl_samples!r}")
        if self.patience is not None and (self.patience < 1 or self.val_fraction == 0):
            raise ValueError(f"patience must be None or a positive integer, with a held-out split (val_fraction > 0); "
                             f"got patience={self.patience!r}, val_fraction={self.val_fraction!r}")


def rgbd_settings() -> dict:
    """Settings that differ for image policies, looked up when a config is made (the epochs follow quick mode).

    A policy that sees the cup only through the camera must learn image features before they pay off;
    with the state-mode warm-up (30% of the epochs) the KL term pruned the whole image stream of the VD network before it was useful (measured: 100% of the
    image stream's weights dropped, held-out MSE 0.043 vs L2's 0.028). Raising beta over all epochs
    keeps the stream alive (held-out MSE 0.022). Epochs are fewer because an image epoch costs ~500x a
    state epoch on a CPU.
    """
    return {"epochs": budget(40, 2), "beta_warmup": 1.0}


def default_config(reg: str = "vd", obs_mode: str = "state") -> PretrainConfig:
    """The pre-training settings used for shipped checkpoints and experiments, per observation mode, with RL
    starting from ``RL_START_SIGMA``."""
    return PretrainConfig(reg=reg, obs_mode=obs_mode, initial_sigma=RL_START_SIGMA,
                          **(rgbd_settings() if obs_mode == "rgbd" else {}))


def observation_space(task: str, obs_mode: str, image_size: int = 128) -> gym.Space:
    env = gym.make(ENV_IDS[task], obs_mode=obs_mode, image_size=image_size)
    space = env.observation_space
    env.close()
    return space


def demo_observations(demos: Demos, obs_mode: str, image_size: int = 128, progress: bool = False,
                      indices: np.ndarray | None = None):
    """The policy inputs of the samples ``indices`` (default: every sample): the state vectors, or RGBD
    images re-rendered from the stored states (RGB as the env's uint8, depth as float16 to halve its
    memory; converted per batch)."""
    indices = np.arange(len(demos)) if indices is None else np.asarray(indices)
    if obs_mode == "state":
        return demos.states[indices]
    env = gym.make(ENV_IDS[demos.meta["task"]], obs_mode="rgbd", image_size=image_size)
    rgb = np.empty((len(indices), 3, image_size, image_size), dtype=np.uint8)
    depth = np.empty((len(indices), image_size * image_size), dtype=np.float16)
    for k, i in enumerate(tqdm(indices, desc="rendering demonstration images", disable=not progress)):
        obs = env.unwrapped.observation_at(demos.joints[i], demos.cup[i, :2])
        rgb[k], depth[k] = obs["rgb"], obs["depth"]
    env.close()
    return {"rgb": rgb, "depth": depth, "joints": demos.joints[indices].astype(np.float32)}


def _take(obs, idx, device: torch.device | None = None):
    """The observations ``idx`` of ``obs`` (an array or a dict of arrays) as tensors, on ``device`` when given."""
    if isinstance(obs, dict):
        return {k: obs_to_tensor(v[idx], device) for k, v in obs.items()}
    return obs_to_tensor(obs[idx], device)


def split_by_episode(demos: Demos, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the training and held-out samples, holding out whole episodes."""
    episodes = np.unique(demos.episode)
    rng = np.random.default_rng(seed)
    held = rng.permutation(episodes)[: int(round(val_fraction * len(episodes)))]
    is_val = np.isin(demos.episode, held)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


class HeldOutStop:
    """Early stopping on the held-out MSE (``PretrainConfig.patience``): remembers the best epoch's mu (counted
    from ``after`` epochs on, the end of VD's KL warm-up) and says when ``patience`` epochs have not beaten it."""

    def __init__(self, patience: int, after: int = 0):
        self.patience, self.after = patience, after
        self.best_mse, self.best_epoch, self.best_state = math.inf, None, None

    def should_stop(self, epoch: int, val_mse: float, net: torch.nn.Module) -> bool:
        if epoch < self.after:
            return False
        if val_mse < self.best_mse:
            self.best_mse, self.best_epoch = val_mse, epoch
            self.best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        return epoch - self.best_epoch >= self.patience

    def restore(self, net: torch.nn.Module) -> None:
        """Put the best epoch's parameters back into ``net`` (nothing to do if no epoch counted)."""
        if self.best_state is not None:
            net.load_state_dict(self.best_state)


def pretrain(demos: Demos, config: PretrainConfig | None = None, seed: int = 0, progress: bool = True,
             observations=None, spread_net=None,
             device: torch.device | str = "cpu") -> tuple[GaussianPolicy, list[dict]]:
    """Behavioural cloning of ``demos`` with the chosen regulariser (default: ``PretrainConfig()``, the paper's
    setting; the experiments pass :func:`default_config`), then sigma set by ``config.initial_sigma``
    (:func:`set_initial_sigma`). Returns the
    policy (in eval mode, sigma trainable again; a VD policy is not yet pruned: call ``policy.prune_()``
    to start RL) and one log row per epoch.
    ``observations`` may pass inputs already made by :func:`demo_observations`; ``spread_net``: the VD mean
    network whose spread an L2 policy follows under ``initial_sigma="spread"``. ``device``: where the cloning
    runs (:func:`vdtutorial.policy.torch_device`; "cuda" for a GPU): the policy and each minibatch move there,
    and the policy comes back to the CPU before sigma is set, so it is returned on the CPU. A GPU gives the
    same computation up to floating-point rounding (and other random draws for VD's weight noise).

    Both use Adam, minibatches of ``batch_size``, a held-out split by whole episodes (samples of one
    trajectory are strongly correlated; splitting by sample would leak), and log per epoch the training
    loss, the held-out mean squared error of the (deterministic, pruned) mean action and, for VD, the
    fraction of weights of ``mu`` with log alpha > 3.

    When mu is cloned, the sigma network is set by ``initial_sigma``, the option that decides what sigma RL
    starts from (:mod:`vdtutorial.beyond.initial_sigma`): a fixed value (the paper's setting, the default 0.3), a
    maximum-likelihood fit to the demonstrations, or a fit to the VD network's predictive spread.
    """
    cfg = config or PretrainConfig()
    device = torch_device(device)  # refused before any work when this machine has no such device
    torch.manual_seed(seed)
    task = demos.meta["task"]
    space = observation_space(task, cfg.obs_mode, cfg.image_size)
    policy = make_policy(space, demos.actions.shape[1], variational=cfg.reg == "vd")
    policy.sigma.requires_grad_(False)
    obs = observations if observations is not None else demo_observations(demos, cfg.obs_mode, cfg.image_size, progress)
    actions = torch.as_tensor(demos.actions, dtype=torch.float32)
    train_idx, val_idx = split_by_episode(demos, cfg.val_fraction, seed)
    n_train = len(train_idx)
    with on_device(policy, device):  # the cloning only: sigma is set, and the policy returned, on the CPU
        params = list(policy.mu.parameters())
        weights = [p for name, p in policy.mu.named_parameters() if name.endswith("weight")]
        optimiser = torch.optim.Adam(params, lr=cfg.lr)
        generator = torch.Generator().manual_seed(seed)
        history = []
        bar = tqdm(range(cfg.epochs), desc=f"pre-training ({cfg.reg}, {cfg.obs_mode})", disable=not progress)
        step, total_steps = 0, cfg.epochs * math.ceil(n_train / cfg.batch_size)
        warmup_epochs = math.ceil(cfg.beta_warmup * cfg.epochs) if cfg.reg == "vd" else 0
        stop = None if cfg.patience is None else HeldOutStop(cfg.patience, warmup_epochs)
        for epoch in bar:
            policy.train()
            losses = []
            for batch in torch.randperm(n_train, generator=generator).split(cfg.batch_size):
                idx = train_idx[batch.numpy()]
                o, a = _take(obs, idx, device), actions[idx].to(device)
                nll = -policy.log_prob(o, a).mean()
                if cfg.reg == "vd":
                    beta = min(1.0, step / max(1.0, cfg.beta_warmup * total_steps))
                    loss = nll + beta * model_kl(policy.mu) / (cfg.kl_samples or n_train)
                else:
                    loss = nll + cfg.l2 * sum((w ** 2).sum() for w in weights)
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                losses.append(loss.item())
                step += 1
            row = {"epoch": epoch + 1, "train_loss": float(np.mean(losses)),
                   **evaluate_imitation(policy, obs, actions, val_idx)}
            if cfg.reg == "vd":
                row["weights_pruned"] = pruned_fraction(policy.mu)
            history.append(row)
            bar.set_postfix(loss=f"{row['train_loss']:.3f}", val_mse=f"{row['val_mse']:.4f}")
            if stop is not None and stop.should_stop(epoch + 1, row["val_mse"], policy.mu):
                break
        if stop is not None:
            stop.restore(policy.mu)
    policy.eval()
    policy.sigma.requires_grad_(True)  # frozen for behavioural cloning only: the RL phase trains sigma too
    sigma_record = set_initial_sigma(policy, demos, cfg, seed, obs, spread_net)
    policy.pretrain_info = {"config": asdict(cfg), "seed": seed, "demos": dict(demos.meta), "history": history,
                            "initial_sigma": sigma_record,
                            **({} if stop is None else {"epochs_run": len(history), "best_epoch": stop.best_epoch})}
    return policy, history


def set_initial_sigma(policy: GaussianPolicy, demos: Demos, config: PretrainConfig, seed: int,
                      observations=None, spread_net=None) -> dict:
    """Set the sigma that RL starts from by ``config.initial_sigma`` (:mod:`vdtutorial.beyond.initial_sigma`),
    fitting on the training split of pre-training with ``seed`` (options b and c). Also applies to a
    policy read back from a checkpoint made with another option: mu is the same whatever the option.
    Returns what was done (kind, and for a fit its losses and the resulting sigma)."""
    spec = InitialSigma.parse(config.initial_sigma)
    if spec.kind == "fixed":
        return apply_initial_sigma(policy, spec)
    if spec.kind == "spread" and spread_net is None and not policy.config["variational"]:
        raise ValueError("initial_sigma='spread' follows the VD network's spread: an L2 policy needs the VD "
                         "network pre-trained on the same demonstrations (spread_net)")
    fit_idx, _ = split_by_episode(demos, config.val_fraction, seed)
    if config.obs_mode == "rgbd" and len(fit_idx) > IMAGE_FIT_STATES:  # cost: a seeded subset (initial_sigma)
        fit_idx = np.sort(np.random.default_rng(seed).choice(fit_idx, IMAGE_FIT_STATES, replace=False))
    if observations is None:
        obs = obs_to_tensor(demo_observations(demos, config.obs_mode, config.image_size, indices=fit_idx))
    else:
        obs = _take(observations, fit_idx)
    actions = torch.as_tensor(demos.actions[fit_idx], dtype=torch.float32)
    return apply_initial_sigma(policy, spec, obs, actions, spread_net, seed)


@torch.no_grad()
def evaluate_imitation(policy: GaussianPolicy, obs, actions: torch.Tensor, idx: np.ndarray, batch: int = 500) -> dict:
    """Held-out mean squared error of the mean action (eval mode: deterministic, log alpha > 3 dropped)
    and mean log-likelihood of the expert's actions, computed on the device the policy is on."""
    if len(idx) == 0:
        return {"val_mse": float("nan"), "val_loglik": float("nan")}
    was_training = policy.training
    policy.eval()
    device = next(policy.parameters()).device
    se = ll = 0.0
    for start in range(0, len(idx), batch):
        part = idx[start:start + batch]
        dist, expert = policy.distribution(_take(obs, part, device)), actions[part].to(device)
        se += ((dist.mean - expert) ** 2).sum().item()
        ll += dist.log_prob(expert).sum().item()
    policy.train(was_training)
    return {"val_mse": se / (len(idx) * actions.shape[1]), "val_loglik": ll / len(idx)}


# -- checkpoints -----------------------------------------------------------------------------------------

def pretrain_command(reg: str, demos_path, seed: int, obs_mode: str, initial_sigma: str = PAPER_INITIAL_SIGMA) -> str:
    """The command line that makes a checkpoint, as its meta records it (the data set's path relative to the
    folder holding data/, so that a shipped checkpoint names no machine)."""
    sigma = "" if initial_sigma == PAPER_INITIAL_SIGMA else f" --sigma {initial_sigma}"
    return f"python -m vdtutorial pretrain --reg {reg} --demos {recorded_path(demos_path)} --seed {seed} --obs {obs_mode}{sigma}"


def checkpoint_path(demos_meta: dict, reg: str, obs_mode: str, seed: int = 0, root: Path | None = None,
                    initial_sigma: str = PAPER_INITIAL_SIGMA, kl_samples: int | None = None,
                    data_name: str | None = None, patience: int | None = None) -> Path:
    """Conventional checkpoint name under ``data/checkpoints``; a non-default ``initial_sigma``, ``kl_samples``
    or ``patience`` is added to the name (``..._seed0_initsigma-demos.pt``, ``..._seed0_kl7200.pt``,
    ``..._seed0_stop10.pt``), so that it never replaces the default checkpoint. ``data_name`` names the data set in place of its
    ``TASK_nSAMPLES_sigmaSIGMA``: a set made in rounds (DART's, DAgger's) has no Sigma to be named by."""
    m = demos_meta
    sigma = "" if initial_sigma == PAPER_INITIAL_SIGMA else f"_initsigma-{initial_sigma}"
    kl = "" if kl_samples is None else f"_kl{kl_samples}"
    stop = "" if patience is None else f"_stop{patience}"
    data = data_name or data_set_name(m["task"], m["samples"], m["noise"])
    return Path(root or data_dir()) / "checkpoints" / f"{data}_{reg}_{obs_mode}_seed{seed}{kl}{stop}{sigma}.pt"


def save_checkpoint(policy: GaussianPolicy, path, extra: dict | None = None) -> Path:
    """``state_dict`` plus the policy's config and how it was made; written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"vdtutorial": vdtutorial.__version__, **getattr(policy, "pretrain_info", {}), **(extra or {})}
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # two workers may make the same checkpoint
    torch.save({"config": policy.config, "state_dict": policy.state_dict(), "meta": meta}, tmp)
    tmp.replace(path)
    return path


#: The conventional file name of :func:`checkpoint_path`, read back to fill in a make-it hint.
_NAME = re.compile(DATA_SET_PATTERN + r"_(?P<reg>vd|l2)_(?P<obs>state|rgbd)_seed(?P<seed>\d+)\.pt")


def _make_hint(path: Path) -> str:
    """The command that makes the checkpoint ``path``, with the real values when the name is conventional."""
    match = _NAME.fullmatch(path.name)
    if not match:
        return "Make it with: python -m vdtutorial pretrain --reg {vd,l2} --demos FILE --seed SEED --obs {state,rgbd} --out " + str(path)
    demos = demo_path(match["task"], int(match["samples"]), float(match["noise"]), 0)
    return (f"Make it with: {pretrain_command(match['reg'], demos, int(match['seed']), match['obs'])} --out {path}")


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
        blob = torch.load(path, map_location="cpu", weights_only=True)
        config, state, meta = blob["config"], blob["state_dict"], blob.get("meta", {})
    except Exception as exc:  # torch raises several types for a damaged or foreign file
        raise CheckpointError(f"checkpoint {path} is corrupt or not a vdtutorial checkpoint ({exc}). {fix}") from exc
    # checkpoints made before ``initial_sigma`` existed started RL from the fixed default
    where = {"initial_sigma": PAPER_INITIAL_SIGMA, **meta.get("demos", {}), **meta.get("config", {}), **config}
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
