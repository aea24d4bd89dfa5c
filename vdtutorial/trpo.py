r"""Trust Region Policy Optimization (Schulman et al., 2015), written out in one file.

This is the reinforcement-learning stage of the paper: a policy pre-trained by behavioural cloning
(with sparse variational dropout or L2) is fine-tuned with TRPO. The paper used rllab's TRPO with
200 environment steps per iteration and a horizon of 25 steps; the defaults below follow that.

One iteration, as pseudocode::

    1. collect   run pi_old for `steps_per_iter` steps in the vector environment (one policy
                 forward per vector step); episodes that end are reset in the same step; the
                 trajectories still running when the batch is full are cut off there
    2. advantage V(s, t) = the baseline fitted on the previous batch (rllab's linear one, or
                 optionally a value network);
                 A = GAE(gamma, lambda) of the rewards against V, bootstrapped with V where a
                 trajectory was cut off by the batch end (and, optionally, where an episode hit its
                 time limit); then normalise A to mean 0, std 1
    3. gradient  g = grad of the surrogate L(theta) = mean[ pi_theta(a|s) / pi_old(a|s) * A ]
    4. direction s ~= F^-1 g by conjugate gradient, where F v is a Fisher-vector product: the
                 Hessian of the mean KL(pi_old || pi_theta) times v, plus damping * v; the mean
                 KL of this step may be taken over a random subset of the batch (``fvp_subsample``);
                 for the paper's Gaussian policy F v is computed in its cheaper Gauss-Newton form
                 J^T M J v (:mod:`vdtutorial.fisher`), for any other policy by a double backward
    5. step      beta = sqrt(2 delta / s^T F s), so the full step beta * s has a quadratic-model
                 KL of exactly delta
    6. search    try theta_old + beta s, then halve the step; accept the first one whose mean
                 KL is <= delta AND whose surrogate improved; if none, keep theta_old
    7. baseline  refit the baseline on this batch: the linear one on the discounted returns, the
                 value network on the lambda-returns A + V (before normalising A)

What is optimised is exactly ``[p for p in policy.parameters() if p.requires_grad]``. Frozen
parameters (variational dropout's log sigma^2 in the RL stage) therefore never move, and a weight
that the forward pass multiplies by a 0/1 pruning mask gets a gradient of exactly 0, a Fisher-vector
product of exactly 0, and so a step of exactly 0: pruned weights stay pruned.

Policy protocol (see ``vdtutorial.policy``): an ``nn.Module`` whose ``distribution(obs)`` returns a
diagonal ``torch.distributions.Normal`` for a float32 tensor of shape (B, d) or a dict of such
tensors; log-probabilities are summed over the last dimension. It must be a deterministic function
of (obs, parameters): the KL at the old parameters must be 0.

Reproducibility: every iteration is a pure function of (seed, iteration index, parameters and
baseline at its start). At the start of an iteration the vector environment is reset with seeds
derived from (seed, iteration) and the action noise comes from a ``torch.Generator`` seeded from the
same pair. A checkpoint (policy, baseline, iteration index, log rows) therefore resumes a run
exactly.

Vector environments: gymnasium >= 1.0 autoresets a finished sub-environment either on the same step
(its final observation and info go into ``info["final_obs"]`` / ``info["final_info"]``) or on the
next step (which then ignores the action). We require ``AutoresetMode.SAME_STEP`` so that every
step in the batch is a real transition; :func:`make_vec_env` builds such a vector environment.
"""
from __future__ import annotations

import csv
import math
import os
import time
from dataclasses import asdict, dataclass
from typing import Callable

import gymnasium
import numpy as np
import torch
from torch import nn
from torch.distributions import Normal, kl_divergence
from tqdm.auto import tqdm

from vdtutorial.fisher import GaussNewtonFisher
from vdtutorial.fisher import supports as supports_gauss_newton
from vdtutorial.policy import obs_to_tensor

Obs = np.ndarray | dict[str, np.ndarray]
TensorObs = torch.Tensor | dict[str, torch.Tensor]
#: The ways :class:`TRPO` can compute Fisher-vector products (its ``fisher`` argument).
FISHER_PRODUCTS = ("auto", "gauss_newton", "double_backward")


# ----------------------------------------------------------------------------------------------
# Hyperparameters
# ----------------------------------------------------------------------------------------------
#: The baselines TRPOConfig.baseline can name: rllab's linear one and a value network.
BASELINES = ("linear", "mlp")


@dataclass
class TRPOConfig:
    """TRPO hyperparameters. ``steps_per_iter`` is the paper's; the paper reports no others, so
    ``max_kl``, ``cg_iters`` and ``fvp_subsample`` are rllab's defaults and the rest are common
    choices.

    steps_per_iter: environment steps per iteration, summed over the sub-environments of the
        vector environment (must be a multiple of their number). The paper uses 200 with a
        horizon of 25, i.e. 8 trajectories per batch. Larger batches give less noisy gradients
        but fewer updates for the same budget.
    gamma: discount factor of the returns. Over the paper's 25-step horizon 0.99 discounts the
        last reward by only 0.99^25 = 0.78, so the final success bonus still counts from step 0.
    gae_lambda: GAE's lambda, trading bias (0: one-step TD with the baseline) against variance
        (1: Monte-Carlo returns minus the baseline).
    max_kl: delta, the trust-region radius: the largest mean KL(pi_old || pi_new) over the batch
        that an accepted step may have. 0.01 is the value from the TRPO paper and rllab.
    cg_iters: conjugate-gradient iterations used to approximate F^-1 g. 10 is enough to get a good
        direction without ever building F (which has as many rows as the policy has parameters).
    fvp_subsample: the fraction of the batch on which the Fisher-vector products are computed (at
        least one sample); a random subset, drawn per iteration from the iteration's seed. The
        gradient g, the step size and the line search's KL check still use the whole batch. CG
        needs ``cg_iters + 1`` products, and for image policies they dominate the update: Schulman
        et al. (2015) computed them on 10% of the data. rllab, whose TRPO the paper used, did so
        only in its first release (April 2016): its ``ConjugateGradientOptimizer`` has defaulted to
        ``subsample_factor=1.`` since September 2016, and its TRPO passes no optimiser arguments, so
        the paper (2018) most likely used the whole batch. The Fisher only sets the metric of the
        step, but a small subset sees little of it: with 20 of 200 samples the full step overshoots
        the KL bound, the line search cuts it back, and the policies here learned more slowly per
        step (docs/results.md, chapter 07). 1.0 (the whole batch) is the default; smaller values are a
        speed option and a control.
    cg_damping: added to the Fisher matrix (F + damping * I) so that CG works on a well-conditioned
        positive-definite matrix even when F is singular, e.g. along the directions of pruned
        weights or with fewer samples than parameters.
    backtrack_iters: how many step sizes the line search tries (full step, then halved each time)
        before giving up and keeping the old parameters.
    backtrack_coeff: the factor by which the line search shrinks the step each time.
    baseline_reg: ridge coefficient of the linear baseline's least-squares fit (rllab's value);
        it is multiplied by 10 (up to 5 times) if the solve is not finite.
    baseline: ``"linear"`` (the default, and the paper's: rllab's :class:`LinearFeatureBaseline`)
        or ``"mlp"``, a value network (:class:`MLPBaseline`) fitted by a few epochs of Adam per
        iteration, as sb3-contrib and Spinning Up do. The network needs no hand-made features, but
        brings its own hyperparameters (the four ``critic_*`` below, unused by the linear one).
    critic_hidden: widths of the value network's tanh hidden layers.
    critic_lr: Adam's learning rate for the value network.
    critic_epochs: passes over the batch per iteration (sb3-contrib's ``n_critic_updates``).
    critic_batch_size: minibatch size of those passes.
    bootstrap_time_limits: at an episode end caused by a time limit (``truncated`` and not
        ``terminated``), count the value of the final observation, gamma * V(s_final), as if the
        episode went on, instead of 0. False is rllab's (and so the paper's) treatment: rllab's
        sampler stops a path at ``max_path_length`` and appends a value of 0 after every path,
        however it ended, so the horizon is part of the task. True is what sb3 does: the time limit
        then only cuts an endless task into episodes, and V needs no notion of the time left.
    """

    steps_per_iter: int = 200
    gamma: float = 0.99
    gae_lambda: float = 0.97
    max_kl: float = 0.01
    cg_iters: int = 10
    cg_damping: float = 0.1
    backtrack_iters: int = 10
    backtrack_coeff: float = 0.5
    baseline_reg: float = 1e-5
    fvp_subsample: float = 1.0
    baseline: str = "linear"
    critic_hidden: tuple[int, ...] = (64, 64)
    critic_lr: float = 1e-3
    critic_epochs: int = 10
    critic_batch_size: int = 128
    bootstrap_time_limits: bool = False

    def __post_init__(self):
        if not 0.0 < self.fvp_subsample <= 1.0:
            raise ValueError(f"fvp_subsample must be in (0, 1], got {self.fvp_subsample}")
        if self.baseline not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {self.baseline!r}")
        if self.critic_epochs < 1 or self.critic_batch_size < 1:
            raise ValueError(f"critic_epochs and critic_batch_size must be positive, got "
                             f"{self.critic_epochs} and {self.critic_batch_size}")
        self.critic_hidden = tuple(self.critic_hidden)


# ----------------------------------------------------------------------------------------------
# The pieces of TRPO, as pure functions
# ----------------------------------------------------------------------------------------------
def gae(rewards: np.ndarray, values: np.ndarray, last_values: np.ndarray, dones: np.ndarray,
        gamma: float, lam: float) -> np.ndarray:
    """Generalised advantage estimates, one per step.

    Arrays have shape (T, N) (time first; N parallel environments) or (T,). ``values[t]`` is the
    baseline at the state in which the action at step t was taken, ``dones[t]`` is True when the
    episode ended with step t (the next state then has value 0), and ``last_values`` is the
    baseline at the state following the last step, used where the batch cut a trajectory off.

        delta_t = r_t + gamma * V(s_{t+1}) * (1 - done_t) - V(s_t)
        A_t     = delta_t + gamma * lam * (1 - done_t) * A_{t+1}

    With ``lam=1``, ``A + values`` are the discounted returns (bootstrapped at the cut).
    """
    advantages = np.zeros_like(rewards, dtype=np.float64)
    next_value, next_advantage = last_values, 0.0
    for t in reversed(range(len(rewards))):
        alive = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * alive - values[t]
        next_advantage = delta + gamma * lam * alive * next_advantage
        advantages[t] = next_advantage
        next_value = values[t]
    return advantages


def flat_grad(y: torch.Tensor, params: list[nn.Parameter], create_graph: bool = False,
              retain_graph: bool | None = None) -> torch.Tensor:
    """Gradient of the scalar ``y`` with respect to ``params``, concatenated into one vector
    (zeros for parameters that ``y`` does not depend on)."""
    grads = torch.autograd.grad(y, params, create_graph=create_graph, retain_graph=retain_graph,
                                allow_unused=True)
    return torch.cat([(torch.zeros_like(p) if g is None else g).reshape(-1) for p, g in zip(params, grads)])


def fisher_vector_product(kl_grad: torch.Tensor, params: list[nn.Parameter], v: torch.Tensor,
                          damping: float) -> torch.Tensor:
    """(F + damping * I) v without building F.

    F is the Hessian of the mean KL(pi_old || pi_theta) at theta = theta_old, which equals the
    Fisher information matrix of the policy. ``kl_grad`` is the gradient of the mean KL, computed
    once with ``create_graph=True``; differentiating ``kl_grad . v`` once more gives F v (keeping
    the graph of ``kl_grad``, which conjugate gradient differentiates again for the next v). This
    needs nothing but the policy protocol; for the paper's Gaussian policy :mod:`vdtutorial.fisher`
    computes the same product several times faster.
    """
    return flat_grad(kl_grad @ v, params, retain_graph=True) + damping * v


def conjugate_gradient(Avp: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int = 10,
                       residual_tol: float = 1e-10) -> torch.Tensor:
    """Approximately solve A x = b for a symmetric positive-definite A, given only v -> A v.

    Starts at x = 0; each iteration moves along a search direction that is A-conjugate to all the
    previous ones. Stops after ``iters`` iterations or when the squared residual is below
    ``residual_tol``. In exact arithmetic it is exact after dim(b) iterations.
    """
    x = torch.zeros_like(b)
    r = b.clone()  # residual b - A x
    p = b.clone()  # search direction
    r_dot_r = r @ r
    for _ in range(iters):
        if r_dot_r < residual_tol:
            break
        Ap = Avp(p)
        alpha = r_dot_r / (p @ Ap)
        x += alpha * p
        r -= alpha * Ap
        new_r_dot_r = r @ r
        p = r + (new_r_dot_r / r_dot_r) * p
        r_dot_r = new_r_dot_r
    return x


@torch.no_grad()
def set_flat_params(params: list[nn.Parameter], flat: torch.Tensor) -> None:
    """Copy the vector ``flat`` into ``params`` (in place, in order)."""
    start = 0
    for p in params:
        p.copy_(flat[start:start + p.numel()].view_as(p))
        start += p.numel()


def line_search(params: list[nn.Parameter], full_step: torch.Tensor,
                surrogate_and_kl: Callable[[], tuple[torch.Tensor, torch.Tensor]], max_kl: float,
                backtrack_iters: int = 10, backtrack_coeff: float = 0.5,
                surrogate_old: float | None = None) -> tuple[float | None, float, float]:
    """Backtracking line search along ``full_step`` from the current parameters.

    ``surrogate_and_kl()`` evaluates the surrogate and the mean KL(old || current) at the current
    parameters (one policy forward for both). Tries the fractions 1, c, c^2, ... (c =
    ``backtrack_coeff``) of the full step and accepts the first one whose mean KL is at most
    ``max_kl`` and whose surrogate is larger than at the start. Returns (accepted fraction,
    surrogate improvement, mean KL), leaving the parameters at the accepted point; or
    (None, 0.0, 0.0) with the parameters restored when no step passes. ``surrogate_old``, the
    surrogate at the current parameters, saves one evaluation when the caller already has it.
    """
    with torch.no_grad():
        theta_old = torch.cat([p.reshape(-1) for p in params]).clone()
        if surrogate_old is None:
            surrogate_old = surrogate_and_kl()[0].item()
        for i in range(backtrack_iters):
            fraction = backtrack_coeff ** i
            set_flat_params(params, theta_old + fraction * full_step)
            surrogate, kl = (x.item() for x in surrogate_and_kl())
            improvement = surrogate - surrogate_old
            if kl <= max_kl and improvement > 0:
                return fraction, improvement, kl
        set_flat_params(params, theta_old)
    return None, 0.0, 0.0


# ----------------------------------------------------------------------------------------------
# Baseline
# ----------------------------------------------------------------------------------------------
def default_baseline_features(obs: Obs) -> np.ndarray:
    """Low-dimensional baseline features of a batch of observations: the flattened observation,
    or, for dict observations (image + joints), the ``"joints"`` entry."""
    if isinstance(obs, dict):
        if "joints" not in obs:
            raise KeyError("dict observation without a 'joints' entry: pass baseline_features= to TRPO")
        obs = obs["joints"]
    return np.asarray(obs, dtype=np.float64).reshape(len(obs), -1)


class LinearFeatureBaseline:
    """State-value estimate V(s, t) = w . phi(s, t), fitted by ridge regression (as in rllab).

    phi = [f, f^2, t, t^2, t^3, 1] with f = features(s) clipped to [-10, 10] and t the time step
    within the episode divided by 100. Why a linear baseline rather than a value network: with
    200-sample batches a network would have little to learn from and would need its own optimiser
    and hyperparameters, whereas a least-squares fit is closed-form, instant and has no state but
    its weights; the time features capture how the remaining return shrinks towards the horizon;
    and image policies still get a baseline from their low-dimensional features (the joints).
    """

    def __init__(self, reg: float = 1e-5):
        self.reg = reg
        self.weights: np.ndarray | None = None  # None until the first fit: V = 0

    @staticmethod
    def design(features: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        f = np.clip(features, -10.0, 10.0)
        t = np.asarray(timesteps, dtype=np.float64).reshape(-1, 1) / 100.0
        return np.concatenate([f, f ** 2, t, t ** 2, t ** 3, np.ones_like(t)], axis=1)

    def predict(self, features: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        if self.weights is None:
            return np.zeros(len(features))
        return self.design(features, timesteps) @ self.weights

    def fit(self, features: np.ndarray, timesteps: np.ndarray, returns: np.ndarray) -> None:
        X = self.design(features, timesteps)
        reg = self.reg
        for _ in range(5):
            weights = np.linalg.solve(X.T @ X + reg * np.eye(X.shape[1]), X.T @ returns)
            if np.all(np.isfinite(weights)):
                break
            reg *= 10
        self.weights = weights

    def state_dict(self) -> dict:
        return {"weights": None if self.weights is None else torch.from_numpy(self.weights)}

    def load_state_dict(self, state: dict) -> None:
        self.weights = None if state["weights"] is None else state["weights"].numpy().copy()


class MLPBaseline:
    """State-value network V(s) = MLP(features(s)), fitted by minibatch Adam on each batch.

    The alternative to :class:`LinearFeatureBaseline` that sb3-contrib and Spinning Up use: a tanh
    MLP regressed (mean squared error) on the batch's value targets for ``epochs`` shuffled passes,
    with one Adam optimiser kept over the whole run. It sees the features only, not the time step:
    it is meant to go with ``bootstrap_time_limits``, under which the value of a state does not
    depend on the time left. Its initial weights and the order of its minibatches come from
    ``seed`` (and the number of fits so far), so a run that saves and reloads it (``state_dict``:
    the weights, Adam's moments and the fit count) continues exactly.
    """

    def __init__(self, num_features: int, hidden: tuple[int, ...] = (64, 64), lr: float = 1e-3,
                 epochs: int = 10, batch_size: int = 128, seed: int = 0):
        with torch.random.fork_rng(devices=[]):  # the global generator (policy init, ...) is untouched
            torch.manual_seed(seed)
            layers, width = [], num_features
            for h in hidden:
                layers += [nn.Linear(width, h), nn.Tanh()]
                width = h
            self.net = nn.Sequential(*layers, nn.Linear(width, 1))
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=lr)
        self.epochs, self.batch_size, self.seed = epochs, batch_size, seed
        self.fits = 0

    def predict(self, features: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.net(torch.as_tensor(features, dtype=torch.float32)).squeeze(-1).double().numpy()

    def fit(self, features: np.ndarray, timesteps: np.ndarray, returns: np.ndarray) -> None:
        x = torch.as_tensor(features, dtype=torch.float32)
        y = torch.as_tensor(returns, dtype=torch.float32)
        order_seed = np.random.SeedSequence([self.seed, self.fits], spawn_key=(1,)).generate_state(1)[0]
        generator = torch.Generator().manual_seed(int(order_seed))
        for _ in range(self.epochs):
            for index in torch.randperm(len(x), generator=generator).split(self.batch_size):
                loss = nn.functional.mse_loss(self.net(x[index]).squeeze(-1), y[index])
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
        self.fits += 1

    def state_dict(self) -> dict:
        return {"net": self.net.state_dict(), "optimizer": self.optimizer.state_dict(), "fits": self.fits}

    def load_state_dict(self, state: dict) -> None:
        self.net.load_state_dict(state["net"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.fits = state["fits"]


# ----------------------------------------------------------------------------------------------
# Environment and data plumbing
# ----------------------------------------------------------------------------------------------
def make_vec_env(env: str | Callable[[], gymnasium.Env], num_envs: int = 1, asynchronous: bool = False,
                 **make_kwargs) -> gymnasium.vector.VectorEnv:
    """A vector environment with same-step autoreset, as TRPO expects.

    ``env`` is a registered id (made with ``gymnasium.make(env, **make_kwargs)``) or a function
    returning an environment. ``asynchronous=True`` runs each copy in its own process.
    """
    make = (lambda: gymnasium.make(env, **make_kwargs)) if isinstance(env, str) else env
    vector_cls = gymnasium.vector.AsyncVectorEnv if asynchronous else gymnasium.vector.SyncVectorEnv
    return vector_cls([make] * num_envs, autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)


def _stack(steps: list[Obs]) -> Obs:
    """T observation batches of shape (N, ...) -> one batch of shape (T * N, ...), time-major."""
    if isinstance(steps[0], dict):
        return {key: _stack([s[key] for s in steps]) for key in steps[0]}
    stacked = np.stack(steps)
    return stacked.reshape(-1, *stacked.shape[2:])


def _batch_of(observations: list[Obs]) -> Obs:
    """Single observations (arrays or dicts of arrays) -> one batch, batch first."""
    if isinstance(observations[0], dict):
        return {key: np.stack([o[key] for o in observations]) for key in observations[0]}
    return np.stack(observations)


def _iteration_seeds(seed: int, iteration: int, num_envs: int) -> tuple[list[int], int]:
    """Environment reset seeds and the action-noise seed of one iteration."""
    state = np.random.SeedSequence([seed, iteration]).generate_state(num_envs + 1)
    return [int(s) for s in state[:-1]], int(state[-1])


@dataclass
class Batch:
    """One iteration's data, flattened over (time, environment) in time-major order."""

    obs: TensorObs                # (n, ...) policy inputs
    actions: torch.Tensor         # (n, action_dim) the sampled (unclipped) actions
    advantages: torch.Tensor      # (n,) normalised GAE advantages
    features: np.ndarray          # (n, k) baseline features of the observations
    timesteps: np.ndarray         # (n,) step index within the episode
    returns: np.ndarray           # (n,) the baseline's regression targets (see TRPOConfig.baseline)
    episode_returns: list[float]  # undiscounted returns of the episodes that ended in the batch
    successes: int                # how many of those ended with info["is_success"] True
    fvp_index: torch.Tensor | None = None  # (m,) the samples of the Fisher-vector products; None = all


# ----------------------------------------------------------------------------------------------
# The algorithm
# ----------------------------------------------------------------------------------------------
class TRPO:
    """TRPO on a gymnasium vector environment.

    policy: the nn.Module to train (see the module docstring for its protocol).
    env: a vector environment with ``AutoresetMode.SAME_STEP`` (see :func:`make_vec_env`) that
        returns fresh observation arrays each step (gymnasium's default ``copy=True``), or a
        zero-argument function that builds one.
    config: hyperparameters, :class:`TRPOConfig`.
    seed: the run's seed; with the parameters it determines every iteration.
    baseline_features: maps a batch of observations (array or dict of arrays, batch first) to a
        float array (batch, k) of low-dimensional features for the baseline (linear or network);
        by default :func:`default_baseline_features`.
    fisher: how the Fisher-vector products of step 4 are computed; both ways are exact and agree to
        float rounding, so this changes the cost, not the algorithm. ``"gauss_newton"``:
        :class:`vdtutorial.fisher.GaussNewtonFisher`, only for a
        :class:`vdtutorial.policy.GaussianPolicy` (:func:`vdtutorial.fisher.supports`);
        ``"double_backward"``: :func:`fisher_vector_product`, for any policy; ``"auto"`` (default):
        the first when the policy supports it, else the second.

    With small policies, ``torch.set_num_threads(1)`` is much faster on a busy 2-core machine:
    extra threads only contend for the cores.
    """

    def __init__(self, policy: nn.Module, env: gymnasium.vector.VectorEnv | Callable[[], gymnasium.vector.VectorEnv],
                 config: TRPOConfig | None = None, seed: int = 0,
                 baseline_features: Callable[[Obs], np.ndarray] | None = None,
                 fisher: str = "auto"):
        if fisher not in FISHER_PRODUCTS:
            raise ValueError(f"fisher must be one of {FISHER_PRODUCTS}, got {fisher!r}")
        if fisher == "gauss_newton" and not supports_gauss_newton(policy):
            raise ValueError("fisher='gauss_newton' needs a GaussianPolicy of Linear/Conv2d/ReLU/Tanh/Flatten "
                             "layers (sparse-VD layers pruned or in eval mode); use 'auto' or 'double_backward'")
        self.fisher = fisher
        self.policy = policy
        self.env = env if isinstance(env, gymnasium.vector.VectorEnv) else env()
        self.config = config or TRPOConfig()
        self.seed = seed
        self.baseline_features = baseline_features or default_baseline_features
        cfg = self.config
        if cfg.baseline == "linear":
            self.baseline = LinearFeatureBaseline(cfg.baseline_reg)
        else:  # the network's input width, from a sample of the (batched) observation space
            num_features = self.baseline_features(self.env.observation_space.sample()).shape[1]
            self.baseline = MLPBaseline(num_features, cfg.critic_hidden, cfg.critic_lr, cfg.critic_epochs,
                                        cfg.critic_batch_size, seed=seed)
        self.params = [p for p in policy.parameters() if p.requires_grad]
        self.iteration_index = 0
        self.rows: list[dict] = []

        mode = self.env.metadata.get("autoreset_mode")
        if mode != gymnasium.vector.AutoresetMode.SAME_STEP:
            raise ValueError(f"TRPO needs a vector env with autoreset_mode=AutoresetMode.SAME_STEP, got {mode}: "
                             "with NEXT_STEP the step after an episode end is a reset, not a transition "
                             "(use vdtutorial.trpo.make_vec_env)")
        if self.config.steps_per_iter % self.env.num_envs:
            raise ValueError(f"steps_per_iter={self.config.steps_per_iter} is not a multiple of "
                             f"num_envs={self.env.num_envs}")
        space = self.env.single_action_space
        self.action_low, self.action_high = space.low, space.high

    # -- 1. collect, 2. advantages ----------------------------------------------------------------
    def collect(self) -> Batch:
        """Run the current policy for one batch and compute its advantages (steps 1-2)."""
        cfg, n = self.config, self.env.num_envs
        steps_per_env = cfg.steps_per_iter // n
        env_seeds, noise_seed = _iteration_seeds(self.seed, self.iteration_index, n)
        generator = torch.Generator().manual_seed(noise_seed)

        obs, _ = self.env.reset(seed=env_seeds)
        t = np.zeros(n, dtype=np.int64)        # step within the current episode, per env
        running_return = np.zeros(n)
        observations, actions, timesteps = [], [], []
        rewards, dones = np.zeros((steps_per_env, n)), np.zeros((steps_per_env, n))
        episode_returns, successes = [], 0
        time_limit_ends = []  # (step, env, final observation, its time step) where a time limit struck

        for k in range(steps_per_env):
            with torch.no_grad():  # one policy forward for all sub-environments
                dist = self.policy.distribution(obs_to_tensor(obs))
                action = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=generator,
                                                              dtype=dist.mean.dtype)
            next_obs, reward, terminated, truncated, info = self.env.step(
                np.clip(action.numpy(), self.action_low, self.action_high))
            done = terminated | truncated
            observations.append(obs)
            actions.append(action)
            timesteps.append(t)
            rewards[k], dones[k] = reward, done
            running_return += reward
            if done.any():
                final = info["final_info"]
                if "is_success" in final:
                    reported = np.flatnonzero(final["_is_success"] & done)
                    successes += sum(bool(final["is_success"][i]) for i in reported)
                episode_returns.extend(running_return[done].tolist())
                running_return[done] = 0.0
                if cfg.bootstrap_time_limits:
                    time_limit_ends += [(k, i, info["final_obs"][i], t[i] + 1)
                                        for i in np.flatnonzero(truncated & ~terminated)]
            t = np.where(done, 0, t + 1)
            obs = next_obs  # after an episode end this is already the next episode's first obs

        # By default a time-limit end counts as the end of the (finite-horizon) task: value 0 after
        # it, as in rllab. With bootstrap_time_limits, gamma * V(final observation) is added to the
        # reward of that last step (the episode still ends there: GAE stops at it). Trajectories cut
        # off by the batch end are always bootstrapped with the baseline.
        flat_obs = _stack(observations)
        features = self.baseline_features(flat_obs)
        flat_t = np.concatenate(timesteps)
        values = self.baseline.predict(features, flat_t).reshape(steps_per_env, n)
        last_values = self.baseline.predict(self.baseline_features(obs), t)
        if time_limit_ends:
            steps, envs, final_obs, final_t = zip(*time_limit_ends)
            final_values = self.baseline.predict(self.baseline_features(_batch_of(final_obs)), np.array(final_t))
            rewards[steps, envs] += cfg.gamma * final_values
        advantages = gae(rewards, values, last_values, dones, cfg.gamma, cfg.gae_lambda)
        if cfg.baseline == "linear":  # rllab: regress on the discounted returns
            returns = gae(rewards, values, last_values, dones, cfg.gamma, 1.0) + values
        else:  # sb3-contrib: regress on the lambda-returns, less noisy targets for a network
            returns = advantages + values
        advantages, returns = advantages.reshape(-1), returns.reshape(-1)
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        fvp_index = None
        if cfg.fvp_subsample < 1.0:  # drawn after the actions, so the rollouts do not depend on it
            size = max(1, int(cfg.steps_per_iter * cfg.fvp_subsample))
            fvp_index = torch.randperm(cfg.steps_per_iter, generator=generator)[:size]
        return Batch(obs=obs_to_tensor(flat_obs), actions=torch.cat(actions),
                     advantages=torch.as_tensor(advantages, dtype=torch.float32), features=features,
                     timesteps=flat_t, returns=returns, episode_returns=episode_returns,
                     successes=successes, fvp_index=fvp_index)

    # -- 3-7. the update --------------------------------------------------------------------------
    def _fisher_product(self, obs: TensorObs, old: Normal,
                        dist: Normal | None = None) -> Callable[[torch.Tensor], torch.Tensor]:
        """v -> (F + damping * I) v, F the Hessian of the mean KL(old || pi_theta) over ``obs`` at the
        current parameters (step 4). ``old`` is the policy's distribution on ``obs`` now; ``dist``,
        when given, is the same with its autograd graph (the double backward reuses it).

        Both forms are exact and agree to float rounding. The Gauss-Newton form
        (:class:`vdtutorial.fisher.GaussNewtonFisher`) is several times cheaper for the image policy but
        needs to know the policy's networks; the double backward (:func:`fisher_vector_product`, the
        teaching version of chapter 06) needs only the policy protocol. ``self.fisher`` chooses."""
        damping = self.config.cg_damping
        if self.fisher == "gauss_newton" or (self.fisher == "auto" and supports_gauss_newton(self.policy)):
            fisher = GaussNewtonFisher(self.policy, obs, old, self.params)
            return lambda v: fisher(v) + damping * v
        dist = dist if dist is not None else self.policy.distribution(obs)
        kl_grad = flat_grad(kl_divergence(old, dist).sum(-1).mean(), self.params, create_graph=True)
        return lambda v: fisher_vector_product(kl_grad, self.params, v, damping)

    def update(self, batch: Batch) -> dict:
        """One TRPO step on ``batch`` (steps 3-6), then refit the baseline (step 7). Returns the
        step's statistics: mean KL, entropy (before the step), surrogate improvement, line search
        outcome (accepted fraction of the full step, or "rejected")."""
        cfg = self.config
        # One forward with graph at theta_old gives pi_old (detached), the surrogate and g.
        dist = self.policy.distribution(batch.obs)
        old = Normal(dist.mean.detach().clone(), dist.stddev.detach().clone())
        old_log_prob = old.log_prob(batch.actions).sum(-1)

        def surrogate_of(dist: Normal) -> torch.Tensor:
            ratio = torch.exp(dist.log_prob(batch.actions).sum(-1) - old_log_prob)
            return (ratio * batch.advantages).mean()

        def surrogate_and_kl() -> tuple[torch.Tensor, torch.Tensor]:
            dist = self.policy.distribution(batch.obs)
            return surrogate_of(dist), kl_divergence(old, dist).sum(-1).mean()

        surrogate = surrogate_of(dist)
        if batch.fvp_index is None:
            g = flat_grad(surrogate, self.params, retain_graph=True)
            Fvp = self._fisher_product(batch.obs, old, dist)
        else:
            g = flat_grad(surrogate, self.params)
            index = batch.fvp_index
            sub_obs = ({k: x[index] for k, x in batch.obs.items()} if isinstance(batch.obs, dict)
                       else batch.obs[index])
            Fvp = self._fisher_product(sub_obs, Normal(old.mean[index], old.stddev[index]))

        direction = conjugate_gradient(Fvp, g, cfg.cg_iters)
        sFs = (direction @ Fvp(direction)).item()
        # Scale so that the quadratic model of the KL, 0.5 * step^T F step, equals max_kl. A zero
        # gradient gives a zero step, which the line search rejects (no improvement).
        full_step = math.sqrt(2 * cfg.max_kl / sFs) * direction if sFs > 0 else torch.zeros_like(direction)
        fraction, improvement, kl = line_search(self.params, full_step, surrogate_and_kl, cfg.max_kl,
                                                cfg.backtrack_iters, cfg.backtrack_coeff, surrogate.item())
        self.baseline.fit(batch.features, batch.timesteps, batch.returns)
        return {"mean_kl": kl, "entropy": old.entropy().sum(-1).mean().item(),
                "surrogate_improvement": improvement,
                "line_search": "rejected" if fraction is None else fraction}

    # -- one iteration, logging, the main loop ----------------------------------------------------
    def iteration(self) -> dict:
        """Collect, update, and return this iteration's log row."""
        start = time.perf_counter()
        batch = self.collect()
        stats = self.update(batch)
        previous_time = self.rows[-1]["wall_time"] if self.rows else 0.0
        row = {"iteration": self.iteration_index,
               "env_steps": (self.iteration_index + 1) * self.config.steps_per_iter,
               "successes": batch.successes,
               "episodes": len(batch.episode_returns),
               "mean_return": float(np.mean(batch.episode_returns)) if batch.episode_returns else math.nan,
               **stats,
               "wall_time": previous_time + time.perf_counter() - start}
        self.rows.append(row)
        self.iteration_index += 1
        return row

    def run(self, total_steps: int, csv_path: str | os.PathLike | None = None,
            checkpoint_path: str | os.PathLike | None = None, progress: bool = True) -> list[dict]:
        """Iterate until ``total_steps`` environment steps (counting iterations already done, e.g.
        before a checkpoint) have been collected. After every iteration the log row is appended to
        ``csv_path`` and a checkpoint is written to ``checkpoint_path`` (when given). Returns all
        log rows so far."""
        total_iters = math.ceil(total_steps / self.config.steps_per_iter)
        with tqdm(total=total_iters, initial=self.iteration_index, disable=not progress, desc="TRPO") as bar:
            while self.iteration_index < total_iters:
                row = self.iteration()
                if csv_path is not None:
                    _append_csv(csv_path, row)
                if checkpoint_path is not None:
                    self.save(checkpoint_path)
                bar.update()
                bar.set_postfix(mean_return=f"{row['mean_return']:.2f}", successes=row["successes"])
        return self.rows

    # -- checkpoints ------------------------------------------------------------------------------
    def checkpoint(self) -> dict:
        """Policy, baseline, iteration index and log rows: everything a run needs to continue exactly
        (TRPO draws its resets and action noise from (seed, iteration), so no generator state is needed)."""
        return {"policy": self.policy.state_dict(), "baseline": self.baseline.state_dict(),
                "iteration": self.iteration_index, "rows": self.rows,
                "seed": self.seed, "config": asdict(self.config)}

    def restore(self, state: dict) -> None:
        """Continue from a :meth:`checkpoint` of a run with the same seed and config."""
        # fields added to TRPOConfig after a checkpoint was written take their defaults, which keep
        # the behaviour of the code that wrote it
        saved_config = {**asdict(TRPOConfig()), **state["config"]}
        if state["seed"] != self.seed or saved_config != asdict(self.config):
            raise ValueError("checkpoint was written with a different seed or config; resuming it would "
                             "not continue the same run")
        self.policy.load_state_dict(state["policy"])
        self.baseline.load_state_dict(state["baseline"])
        self.iteration_index = state["iteration"]
        self.rows = state["rows"]

    def save(self, path: str | os.PathLike) -> None:
        """Write :meth:`checkpoint` to ``path`` (loadable with weights_only=True)."""
        tmp = f"{os.fspath(path)}.tmp"
        torch.save(self.checkpoint(), tmp)
        os.replace(tmp, path)  # a crash mid-write never leaves a half-written checkpoint

    def load(self, path: str | os.PathLike) -> None:
        """Restore a checkpoint written by :meth:`save` (see :meth:`restore`)."""
        self.restore(torch.load(path, weights_only=True))

    def close(self) -> None:
        self.env.close()


def _append_csv(path: str | os.PathLike, row: dict) -> None:
    new_file = not os.path.exists(path) or os.path.getsize(path) == 0
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(row))
        if new_file:
            writer.writeheader()
        writer.writerow(row)
