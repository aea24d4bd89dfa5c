"""Sigma at the start of RL: how the standard deviation of pi(a|s) = N(mu(s), sigma(s)) is set when
pre-training ends. An explicit option, applied the same way to every pre-training method (VD and L2).

Why it matters
    The paper (Section IV) trains only mu in pre-training: "only the parameters of mu_phi(s) are
    trained in this stage, while those of sigma_psi(s) remain fixed". RL therefore starts from whatever
    sigma the initialisation gives, here ``init_std`` = 0.3 rad for every state. The cloned means reach the
    cup often, but sampled with sigma = 0.3 they rarely do, so the first TRPO iterations -- which sample --
    start almost from scratch (the numbers: ``docs/results.md``, "Measurements behind the code"). The paper's
    Section VI names the gap: "the pre-training procedure trains only the mean function mu_phi(s) of the policy, and
    leaves the SD function sigma_psi(s) untouched. Since mu_phi(s)
    is a dropout model, it inherently contains information about its own uncertainty. There is potential
    to use this uncertainty information to learn an appropriate SD function."

Taught in chapter 07 and appendix A4.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from vdtutorial.demos import Demos
from vdtutorial.policy import GaussianPolicy, obs_to_tensor
from vdtutorial.pretrain import (
    PAPER_SIGMA_OPTION,
    SIGMA_FITS,
    PretrainConfig,
    demo_observations,
    observation_rows,
    pretrain,
    set_fixed_sigma,
    sigma_option,
    split_by_episode,
)
from vdtutorial.vd import svdo_layers

KINDS = ("fixed", "demos", "spread")
#: Image policies: the fits use this many training states (a seeded subset) ...
IMAGE_FIT_STATES = 2048
#: ... in minibatches of this size (:class:`InitialSigma`, "How a fit works").
IMAGE_FIT_BATCH = 256
#: The paper's initial sigma, the policy's ``init_std``: the default of option (a).
DEFAULT_VALUE = float(PAPER_SIGMA_OPTION)


@dataclass(frozen=True)
class InitialSigma:
    """Which sigma RL starts from.

    kind: "fixed" (a), "demos" (b) or "spread" (c).
    value: sigma of option (a), radians; also the start of "none" under every option.
    fit_steps, lr: full-batch Adam steps and step size of the fits (b, c).
    spread_samples: weight samples from q(W) per state to estimate the VD spread (c).

    The options (:class:`InitialSigma`, ``kind``)
        ``"fixed"`` (a) -- the paper's setting. The sigma network keeps its initialisation and its output
            bias is set so that sigma = ``value`` (up to the small random head weights, ``HEAD_INIT_SCALE``,
            which make it vary by a few per cent between states). ``value`` = 0.3 = the policy's
            ``init_std`` reproduces today's behaviour bit for bit.
        ``"demos"`` (b) -- sigma_psi(s) fitted by maximum likelihood of the demonstrations with mu frozen:
            the data term of eq. 3, log N(a | mu(s), sigma_psi(s)), maximised over psi only. This is the
            pre-training of Section IV completed for the second moment: sigma then measures how far the
            expert's labels lie from the cloned mean, state by state. It is fitted on the training split of
            pre-training (the held-out episodes stay held out) and applies to every method alike. It raises the
            held-out likelihood of the expert's actions on the shipped sets but can overfit a small one (sigma
            shrinks on training states whose labels mu happens to fit; the numbers: ``docs/results.md``).
            Early stopping on the held-out episodes would guard against it.
        ``"spread"`` (c) -- beyond the paper, its Section VI proposal: sigma_psi(s) fitted to the VD mean
            network's predictive spread, the standard deviation of mu(s) over weights sampled from q(W)
            (eq. 4's multiplicative Gaussian noise, with the weights that RL prunes, log alpha > 3, removed,
            since RL starts from the pruned network). The policy then explores where the dropout model is
            unsure. The fit minimises the squared error of log sigma_psi(s) against the log spread at the
            demonstration states (training split).

    Methods without the ingredient an option needs
        L2 under (c): an L2 network has no noise model, so its sigma is fitted to the spread of the VD
            network pre-trained on the same demonstrations with the same seed (``spread_net``; the method's
            entry in :mod:`vdtutorial.methods` names whose network it follows). Both methods then start with
            the same exploration map and differ only in mu, which is what the comparison of VD against L2 is
            about.
        No pre-training ("none"): there are no demonstrations and no mean network to fit to, so under every
            option it starts from a fixed sigma, ``value`` (0.3 by default, as in the paper).

    How a fit works (b and c)
        mu is evaluated once in eval mode (deterministic, log alpha > 3 dropped: the network RL starts from)
        and frozen. The sigma network, also in eval mode (deterministic for a VD policy too), is trained with
        Adam for ``fit_steps`` steps at learning rate ``lr`` from its initialisation; only its weights and
        biases move (a VD sigma network's log sigma^2 gets no gradient in eval mode and is frozen in RL
        anyway). State inputs: full batch (the sets are small, <= 8000 state vectors, so the fit is exact and
        deterministic). Image inputs: one full-batch step through the convolutional sigma network over 7200
        RGBD images is slow enough on a CPU that 500 of them would take hours; the fit then uses a seeded subset
        of ``IMAGE_FIT_STATES`` training states (chosen in :func:`set_initial_sigma`) and seeded minibatches of
        ``IMAGE_FIT_BATCH`` (minutes per policy). Both numbers are our choices, made for cost; the paper has no such
        fit.

    """

    kind: str = "fixed"
    value: float = DEFAULT_VALUE
    fit_steps: int = 500
    lr: float = 3e-3
    spread_samples: int = 64

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"initial sigma kind must be one of {KINDS}, got {self.kind!r}")
        if not self.value > 0 or self.fit_steps < 1 or self.spread_samples < 2:
            raise ValueError("need value > 0, fit_steps >= 1 and spread_samples >= 2")

    @classmethod
    def parse(cls, text: str | float) -> "InitialSigma":
        """From its command-line / config spelling: a number (option (a) with that value), "demos" or
        "spread"."""
        if isinstance(text, (int, float)):
            return cls("fixed", float(text))
        if text in ("demos", "spread"):
            return cls(text)
        try:
            return cls("fixed", float(text))
        except ValueError:
            raise ValueError(
                f"initial sigma must be a number (a fixed sigma), 'demos' or 'spread', got {text!r}"
            ) from None

    @property
    def spelling(self) -> str:
        """Inverse of :meth:`parse`: what a config or the command line stores."""
        return sigma_option(self.value) if self.kind == "fixed" else self.kind


def _sigma_of(policy, obs) -> torch.Tensor:
    return policy.min_std + F.softplus(policy.sigma(obs))


def _rows(obs, idx):
    """The states ``idx`` of a batch of observations (a tensor, or a dict of tensors for images)."""
    return {k: v[idx] for k, v in obs.items()} if isinstance(obs, dict) else obs[idx]


def _count(obs) -> int:
    return len(next(iter(obs.values()))) if isinstance(obs, dict) else len(obs)


def _in_chunks(net, obs, chunk: int | None) -> torch.Tensor:
    """``net(obs)``, evaluated ``chunk`` states at a time (None: at once) to bound the memory of images."""
    if chunk is None:
        return net(obs)
    n = _count(obs)
    return torch.cat([net(_rows(obs, slice(i, i + chunk))) for i in range(0, n, chunk)])


@torch.no_grad()
def mean_action(policy, obs, chunk: int | None = None) -> torch.Tensor:
    """mu(s) of the network RL starts from: eval mode (deterministic, log alpha > 3 dropped)."""
    was_training = policy.training
    policy.eval()
    out = _in_chunks(policy.mu, obs, chunk)
    policy.train(was_training)
    return out


def gaussian_nll(mu: torch.Tensor, sigma: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Mean over samples of -log N(a | mu, diag(sigma^2)), summed over action dimensions (eq. 3's data
    term with the sign flipped)."""
    return -torch.distributions.Normal(mu, sigma).log_prob(actions).sum(-1).mean()


def _fit_sigma(policy, obs, loss_of_sigma, spec: InitialSigma, batch: int | None = None, seed: int = 0) -> list[float]:
    """Adam on the sigma network's parameters (eval mode) to minimise ``loss_of_sigma(sigma, idx)``, the
    loss of the states ``idx``: the whole batch every step (``batch`` None), or seeded minibatches of
    ``batch`` states (images; :class:`InitialSigma`, "How a fit works")."""
    was_training = policy.training
    policy.eval()
    params = [p for p in policy.sigma.parameters() if p.requires_grad]
    optimiser = torch.optim.Adam(params, lr=spec.lr)
    n, generator = _count(obs), torch.Generator().manual_seed(seed)
    losses = []
    for _ in range(spec.fit_steps):
        idx = slice(None) if batch is None else torch.randperm(n, generator=generator)[:batch]
        loss = loss_of_sigma(_sigma_of(policy, _rows(obs, idx)), idx)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    policy.train(was_training)
    return losses


def fit_sigma_to_demos(
    policy,
    obs,
    actions: torch.Tensor,
    spec: InitialSigma = InitialSigma("demos"),
    batch: int | None = None,
    seed: int = 0,
) -> list[float]:
    """Option (b): maximum likelihood of the demonstrations ``(obs, actions)`` over sigma's parameters,
    mu frozen. Returns the negative log-likelihood per step."""
    mu = mean_action(policy, obs, batch)
    return _fit_sigma(policy, obs, lambda sigma, idx: gaussian_nll(mu[idx], sigma, actions[idx]), spec, batch, seed)


@torch.no_grad()
def vd_spread(mu_net: nn.Module, obs, samples: int = 64, seed: int = 0, chunk: int | None = None) -> torch.Tensor:
    """Predictive standard deviation of a sparse-VD mean network at each state: the std of its output over
    ``samples`` weight draws from q(W) (eq. 4, local reparameterisation: one independent draw per state
    and pass). The weights that RL prunes (log alpha > 3) are removed, variance included, so the spread
    is that of the network RL starts from. Raises for a network without VD layers."""
    layers = svdo_layers(mu_net)
    if not layers:
        raise ValueError(
            "the predictive spread needs a sparse-VD network (option 'spread' takes it from the VD "
            "model: pass spread_net for an L2 policy)"
        )
    net = copy.deepcopy(mu_net)
    for layer in svdo_layers(net):
        keep = layer.keep_mask()
        layer.weight.mul_(keep)
        layer.log_sigma2.masked_fill_(~keep, -80.0)  # exp(-80) ~ 0: a removed weight carries no noise
        layer.pruned.fill_(False)
    net.train()
    generator_state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    draws = torch.stack([_in_chunks(net, obs, chunk) for _ in range(samples)])
    torch.random.set_rng_state(generator_state)
    return draws.std(dim=0)


def fit_sigma_to_spread(
    policy,
    obs,
    spread: torch.Tensor,
    spec: InitialSigma = InitialSigma("spread"),
    batch: int | None = None,
    seed: int = 0,
) -> list[float]:
    """Option (c): least squares of log sigma_psi(s) against log ``spread`` (floored at the policy's
    ``min_std`` plus 1e-4, which sigma cannot go below). Returns the loss per step."""
    target = torch.log(spread.clamp_min(policy.min_std + 1e-4))
    return _fit_sigma(policy, obs, lambda sigma, idx: ((torch.log(sigma) - target[idx]) ** 2).mean(), spec, batch, seed)


def apply_initial_sigma(
    policy,
    spec: InitialSigma,
    obs=None,
    actions: torch.Tensor | None = None,
    spread_net: nn.Module | None = None,
    seed: int = 0,
) -> dict:
    """Set ``policy``'s sigma by option ``spec`` and return a short record of what was done.

    obs, actions: the demonstrations to fit on (options b and c; ignored by a). Image observations (a
        dict) are fitted in minibatches of ``IMAGE_FIT_BATCH``; state vectors in one batch.
    spread_net: the VD mean network whose spread option (c) follows (default: ``policy.mu``, which must
        then be a VD network). seed: seeds the weight draws of the spread and the minibatches."""
    if spec.kind == "fixed":
        return set_fixed_sigma(policy, spec.value)
    if obs is None or actions is None:
        raise ValueError(f"initial sigma {spec.kind!r} is fitted on demonstrations: pass obs and actions")
    actions = torch.as_tensor(actions, dtype=torch.float32)
    batch = IMAGE_FIT_BATCH if isinstance(obs, dict) else None
    if spec.kind == "demos":
        losses = fit_sigma_to_demos(policy, obs, actions, spec, batch, seed)
    else:
        spread = vd_spread(spread_net if spread_net is not None else policy.mu, obs, spec.spread_samples, seed, batch)
        losses = fit_sigma_to_spread(policy, obs, spread, spec, batch, seed)
    with torch.no_grad():
        was_training = policy.training
        policy.eval()
        sigma = _in_chunks(lambda o: _sigma_of(policy, o), obs, batch)
        nll = gaussian_nll(mean_action(policy, obs, batch), sigma, actions).item()
        policy.train(was_training)
    return {
        "kind": spec.kind,
        "states": _count(obs),
        "batch": batch,
        "loss_first": losses[0],
        "loss_last": losses[-1],
        "demos_nll": nll,
        "sigma_mean": sigma.mean().item(),
        "sigma_median": sigma.median().item(),
    }


def set_initial_sigma(
    policy: GaussianPolicy, demos: Demos, config: PretrainConfig, seed: int, observations=None, spread_net=None
) -> dict:
    """Set the sigma that RL starts from by ``config.initial_sigma`` (:class:`InitialSigma`), fitting on the training
    split of pre-training with ``seed`` (options b and c). Also applies to a
    policy read back from a checkpoint made with another option: mu is the same whatever the option.
    Returns what was done (kind, and for a fit its losses and the resulting sigma)."""
    spec = InitialSigma.parse(config.initial_sigma)
    if spec.kind == "fixed":
        return apply_initial_sigma(policy, spec)
    if spec.kind == "spread" and spread_net is None and not policy.config["variational"]:
        raise ValueError(
            "initial_sigma='spread' follows the VD network's spread: an L2 policy needs the VD "
            "network pre-trained on the same demonstrations (spread_net)"
        )
    fit_idx, _ = split_by_episode(demos, config.val_fraction, seed)
    if config.obs_mode == "rgbd" and len(fit_idx) > IMAGE_FIT_STATES:  # cost: a seeded subset (initial_sigma)
        fit_idx = np.sort(np.random.default_rng(seed).choice(fit_idx, IMAGE_FIT_STATES, replace=False))
    if observations is None:
        obs = obs_to_tensor(demo_observations(demos, config.obs_mode, config.image_size, indices=fit_idx))
    else:
        obs = observation_rows(observations, fit_idx)
    actions = torch.as_tensor(demos.actions[fit_idx], dtype=torch.float32)
    return apply_initial_sigma(policy, spec, obs, actions, spread_net, seed)


def pretrain_with_sigma(
    demos: Demos,
    config: PretrainConfig | None = None,
    seed: int = 0,
    progress: bool = True,
    observations=None,
    spread_net: nn.Module | None = None,
    device: torch.device | str = "cpu",
) -> tuple[GaussianPolicy, list[dict]]:
    """:func:`vdtutorial.pretrain.pretrain` with any ``config.initial_sigma``: mu cloned with the paper's fixed
    sigma, then :func:`set_initial_sigma` fits the option's sigma on the same inputs, and the policy's
    ``pretrain_info`` records the option. ``spread_net``: the VD mean network whose spread an L2 policy follows
    under ``initial_sigma="spread"``."""
    cfg = config or PretrainConfig()
    if cfg.initial_sigma not in SIGMA_FITS:
        return pretrain(demos, cfg, seed, progress, observations, device)
    obs = observations if observations is not None else demo_observations(demos, cfg.obs_mode, cfg.image_size, progress)
    policy, history = pretrain(demos, replace(cfg, initial_sigma=PAPER_SIGMA_OPTION), seed, progress, obs, device)
    policy.pretrain_info["config"] = asdict(cfg)
    policy.pretrain_info["initial_sigma"] = set_initial_sigma(policy, demos, cfg, seed, obs, spread_net)
    return policy, history
