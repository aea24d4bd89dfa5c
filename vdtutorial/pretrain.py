"""Behavioural cloning of the IK expert: the pre-training phase of Section IV (Fig. 1, top).

Both regularisers fit the same Gaussian policy pi(a|s) = N(mu(s), sigma(s)) to the data set D of eq. 8
by maximising the log-likelihood of the expert's actions. Only ``mu`` is trained; ``sigma`` keeps its
initial parameters (the paper: "only the parameters of mu are trained in this stage, while those of
sigma remain fixed"), so the likelihood is a weighted squared error whose weights sigma(s)^-2 come
from the untrained sigma network. With sparse VD the whole policy is in training mode, so the sigma
network's layers draw weight noise too: its parameters stay fixed, but each minibatch sees sigma
through fresh noise (a few per cent; what it changes: docs/results.md, "Measurements behind the code").

``reg`` names the method (:mod:`vdtutorial.methods`: its layers, the term added to the likelihood and any noise
put on mu while it is cloned).
``reg="vd"`` -- sparse variational dropout. ``mu`` has SVDO layers and the loss is the negative ELBO of
eqs. 1-3 divided by N (the scale of one sample; the optimum is unchanged):

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
from dataclasses import asdict, dataclass

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from vdtutorial.demos import Demos
from vdtutorial.envs import ENV_IDS
from vdtutorial.methods import CloningStep, method
from vdtutorial.policy import GaussianPolicy, make_policy, map_obs, obs_to_tensor, on_device, torch_device
from vdtutorial.settings import budget

#: The paper's initial-sigma option, as a config spells it: sigma fixed at 0.3, option (a). The default of
#: ``PretrainConfig.initial_sigma`` and the sigma of the checkpoints that experiments cache (mu is the same under
#: every option, which they apply on top) and of checkpoints made before the option existed.
PAPER_SIGMA_OPTION = "0.3"
#: The options of ``PretrainConfig.initial_sigma`` that fit sigma after cloning
#: (:mod:`vdtutorial.experiments.initial_sigma`);
#: any other option is a number, a fixed sigma.
SIGMA_FITS = ("demos", "spread")


def sigma_option(value: str | float) -> str:
    """How a config spells an initial-sigma option: a fixed sigma's number (``0.30`` -> ``"0.3"``) or a fit's name."""
    if value in SIGMA_FITS:
        return value
    try:
        number = float(value)
    except ValueError:
        raise ValueError(
            f"initial sigma must be a number (a fixed sigma), 'demos' or 'spread', got {value!r}"
        ) from None
    if not number > 0:
        raise ValueError(f"a fixed initial sigma must be > 0, got {value!r}")
    return f"{number:g}"


@torch.no_grad()
def set_fixed_sigma(policy: GaussianPolicy, value: float) -> dict:
    """Option (a): set the sigma network's output bias so that sigma = ``value`` (the constructor's formula, so
    ``value`` = ``init_std`` changes nothing). Returns the record ``pretrain_info["initial_sigma"]`` keeps."""
    if not value > policy.min_std:
        raise ValueError(f"a fixed sigma must exceed the policy's floor min_std = {policy.min_std}, got {value}")
    policy.sigma.head[0].bias.fill_(math.log(math.expm1(value - policy.min_std)))
    return {"kind": "fixed", "value": value}


@dataclass
class PretrainConfig:
    """Hyperparameters of behavioural cloning.

    reg: the method, a name in the table of :mod:`vdtutorial.methods` that pre-trains (default: sparse VD).
    epochs: passes over the training split; ``None`` (the default) takes 150, or a few in quick mode, when
        the config is made.
    batch_size: M in eq. 3.
    lr: Adam's step size.
    beta_warmup: fraction of the epochs over which the KL weight beta rises from 0 to 1 (VD only).
    l2: weight-decay coefficient of the L2 baseline (L2 only).
    val_fraction: fraction of the episodes held out.
    image_size: camera image side for ``obs_mode="rgbd"``.
    kl_divisor: the N that divides the KL term of the ELBO (VD only). Eq. 3 sums the likelihood over the N
        samples of D and adds the KL once, so per sample the KL weighs 1/N: ``None`` (the default) takes the
        training split's size, as eq. 3 reads. A fixed number keeps the prior's weight per sample the same
        across data sets of different sizes (Table I); the paper does not say which it used.
    initial_sigma: sigma at the start of RL, set after mu is cloned: a number (option (a), that fixed sigma;
        default: the paper's 0.3), or a fit, "demos" (b) or "spread" (c), which
        :func:`vdtutorial.experiments.initial_sigma.pretrain_with_sigma` runs. It does not change mu.
    patience: stop on the held-out loss. ``None`` (the default, the shipped checkpoints' setting): run all
        ``epochs``. A number P: ``epochs`` becomes a cap, and cloning stops once the held-out MSE of the mean action
        has not improved for P epochs; mu is then the best epoch's. For VD the count starts when the KL warm-up is
        over (before it, the objective itself is still changing). The paper does not say how long it cloned.
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
    kl_divisor: int | None = None
    initial_sigma: str = PAPER_SIGMA_OPTION
    patience: int | None = None

    def __post_init__(self):
        if self.epochs is None:
            self.epochs = budget(150, 4)
        self.initial_sigma = sigma_option(self.initial_sigma)
        try:
            method(self.reg)
        except ValueError as exc:
            raise ValueError(f"reg: {exc}") from None
        if self.obs_mode not in ("state", "rgbd"):
            raise ValueError(f"obs_mode must be 'state' or 'rgbd', got {self.obs_mode!r}")
        if self.epochs < 1 or self.batch_size < 1 or not 0 <= self.val_fraction < 1:
            raise ValueError("epochs and batch_size must be >= 1 and val_fraction in [0, 1)")
        if self.kl_divisor is not None and self.kl_divisor < 1:
            raise ValueError(f"kl_divisor must be None or a positive integer, got {self.kl_divisor!r}")
        if self.patience is not None and (self.patience < 1 or self.val_fraction == 0):
            raise ValueError(
                f"patience must be None or a positive integer, with a held-out split (val_fraction > 0); "
                f"got patience={self.patience!r}, val_fraction={self.val_fraction!r}"
            )


def observation_space(task: str, obs_mode: str, image_size: int = 128) -> gym.Space:
    env = gym.make(ENV_IDS[task], obs_mode=obs_mode, image_size=image_size)
    space = env.observation_space
    env.close()
    return space


def demo_observations(
    demos: Demos, obs_mode: str, image_size: int = 128, progress: bool = False, indices: np.ndarray | None = None
):
    """The policy inputs of the samples ``indices`` (default: every sample): the state vectors, or RGBD
    images re-rendered from the stored states (:meth:`Demos.observations`; depth as float16 to halve its
    memory, converted per batch) with the stored joint angles."""
    indices = np.arange(len(demos)) if indices is None else np.asarray(indices)
    if obs_mode == "state":
        return demos.states[indices]
    env = gym.make(ENV_IDS[demos.meta["task"]], obs_mode="rgbd", image_size=image_size)
    obs = demos.observations(env, indices, depth_dtype=np.float16, progress=progress)
    env.close()
    return {"rgb": obs["rgb"], "depth": obs["depth"], "joints": demos.joints[indices].astype(np.float32)}


def observation_rows(obs, idx, device: torch.device | None = None):
    """The observations ``idx`` of ``obs`` (an array or a dict of arrays) as tensors, on ``device`` when given."""
    return obs_to_tensor(map_obs(lambda x: x[idx], obs), device)


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


def pretrain(
    demos: Demos,
    config: PretrainConfig | None = None,
    seed: int = 0,
    progress: bool = True,
    observations=None,
    device: torch.device | str = "cpu",
) -> tuple[GaussianPolicy, list[dict]]:
    """Behavioural cloning of ``demos`` with the method ``config.reg`` (default: ``PretrainConfig()``, the paper's
    setting; the experiments pass ``experiments.checkpoints.default_config``), then sigma fixed at
    ``config.initial_sigma`` (:func:`set_fixed_sigma`). Returns the policy (in eval mode, sigma trainable again;
    a VD policy is not yet pruned: call ``policy.prune_()`` to start RL) and one log row per epoch.
    ``observations`` may pass inputs already made by :func:`demo_observations`. ``device``: where the cloning
    runs ("cuda": a GPU, the same computation up to rounding); the policy is returned on the CPU.

    Both use Adam, minibatches of ``batch_size``, a held-out split by whole episodes (samples of one
    trajectory are strongly correlated; splitting by sample would leak), and log per epoch the training
    loss, the held-out mean squared error of the (deterministic, pruned) mean action and what the method records
    (:meth:`~vdtutorial.methods.Method.epoch_record`: for VD, the fraction of weights of ``mu`` with log alpha > 3).

    A fitted initial sigma ("demos", "spread") is beyond the paper:
    :func:`vdtutorial.experiments.initial_sigma.pretrain_with_sigma`.
    """
    cfg = config or PretrainConfig()
    entry = method(cfg.reg)
    if not entry.pretrains:
        raise ValueError(f"method {cfg.reg!r} does not pre-train")
    if cfg.initial_sigma in SIGMA_FITS:
        raise ValueError(
            f"initial_sigma={cfg.initial_sigma!r} is fitted after cloning: use "
            "vdtutorial.experiments.initial_sigma.pretrain_with_sigma (pretrain fixes sigma only)"
        )
    device = torch_device(device)  # refused before any work when this machine has no such device
    torch.manual_seed(seed)
    task = demos.meta["task"]
    space = observation_space(task, cfg.obs_mode, cfg.image_size)
    policy = make_policy(space, demos.actions.shape[1], variational=entry.variational)
    policy.sigma.requires_grad_(False)
    obs = observations if observations is not None else demo_observations(demos, cfg.obs_mode, cfg.image_size, progress)
    actions = torch.as_tensor(demos.actions, dtype=torch.float32)
    train_idx, val_idx = split_by_episode(demos, cfg.val_fraction, seed)
    n_train = len(train_idx)
    # the cloning only: sigma is set, and the policy returned, on the CPU; the method's noise lasts as long
    with on_device(policy, device), entry.cloning(policy.mu):
        params = list(policy.mu.parameters())
        optimiser = torch.optim.Adam(params, lr=cfg.lr)
        generator = torch.Generator().manual_seed(seed)
        history = []
        bar = tqdm(range(cfg.epochs), desc=f"pre-training ({cfg.reg}, {cfg.obs_mode})", disable=not progress)
        step, total_steps = 0, cfg.epochs * math.ceil(n_train / cfg.batch_size)
        stop = None if cfg.patience is None else HeldOutStop(cfg.patience, entry.warmup_epochs(cfg))
        for epoch in bar:
            policy.train()
            losses = []
            for batch in torch.randperm(n_train, generator=generator).split(cfg.batch_size):
                idx = train_idx[batch.numpy()]
                o, a = observation_rows(obs, idx, device), actions[idx].to(device)
                nll = -policy.log_prob(o, a).mean()
                penalty = entry.penalty(policy.mu, CloningStep(step, total_steps, n_train, cfg))
                loss = nll if penalty is None else nll + penalty
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                losses.append(loss.item())
                step += 1
            row = {
                "epoch": epoch + 1,
                "train_loss": float(np.mean(losses)),
                **evaluate_imitation(policy, obs, actions, val_idx),
                **entry.epoch_record(policy.mu),
            }
            history.append(row)
            bar.set_postfix(loss=f"{row['train_loss']:.3f}", val_mse=f"{row['val_mse']:.4f}")
            if stop is not None and stop.should_stop(epoch + 1, row["val_mse"], policy.mu):
                break
        if stop is not None:
            stop.restore(policy.mu)
    policy.eval()
    policy.sigma.requires_grad_(True)  # frozen for behavioural cloning only: the RL phase trains sigma too
    sigma_record = set_fixed_sigma(policy, float(cfg.initial_sigma))
    policy.pretrain_info = {
        "config": asdict(cfg),
        "seed": seed,
        "demos": dict(demos.meta),
        "history": history,
        "initial_sigma": sigma_record,
        **({} if stop is None else {"epochs_run": len(history), "best_epoch": stop.best_epoch}),
    }
    return policy, history


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
        part = idx[start : start + batch]
        dist, expert = policy.distribution(observation_rows(obs, part, device)), actions[part].to(device)
        se += ((dist.mean - expert) ** 2).sum().item()
        ll += dist.log_prob(expert).sum().item()
    policy.train(was_training)
    return {"val_mse": se / (len(idx) * actions.shape[1]), "val_loglik": ll / len(idx)}
