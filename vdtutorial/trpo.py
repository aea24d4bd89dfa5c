r"""Trust Region Policy Optimization (Schulman et al., 2015), with which the paper fine-tunes its pre-trained policy
(rllab's; 200 steps per iteration, 25-step horizons: :class:`TRPOConfig`). Taught in chapters 06a and 06b.

One iteration (:meth:`TRPO.iterate`), as pseudocode::

    1. collect   run pi_old for `steps_per_iter` steps in the vector environment          (rollout)
    2. advantage A = GAE(gamma, lambda) of the rewards against the baseline V fitted on the previous
                 batch (:mod:`vdtutorial.baselines`), bootstrapped with V where the batch end cut a
                 trajectory off; then normalised to mean 0, std 1                (advantages_and_returns)
    3. gradient  g = grad of the surrogate L(theta) = mean[ pi_theta(a|s) / pi_old(a|s) * A ]
    4. direction s ~= F^-1 g by conjugate gradient on Fisher-vector products F v (F: the Hessian of the mean
                 KL(pi_old || pi_theta), plus damping), by double backward (``TRPO(fvp=...)`` takes another)
    5. step      beta = sqrt(2 delta / s^T F s): the full step beta * s has a quadratic-model KL of delta
    6. search    halve the step until its mean KL is <= delta and the surrogate improved, else keep
                 theta_old (the numerics of steps 3-6: :mod:`vdtutorial.trust_region`)
    7. baseline  refit V on this batch

Only ``[p for p in policy.parameters() if p.requires_grad]`` moves: frozen parameters (VD's log sigma^2)
never do, and a weight that the forward pass multiplies by a 0/1 pruning mask gets a gradient, a Fisher
product and so a step of exactly 0: pruned weights stay pruned. Every iteration is a pure function of
(seed, iteration index, parameters and baseline at its start), so a checkpoint resumes a run exactly.
"""

from __future__ import annotations

import csv
import math
import os
import time
from dataclasses import asdict, dataclass, replace
from typing import Callable

import gymnasium
import numpy as np
import torch
from torch import nn
from torch.distributions import Normal
from tqdm.auto import tqdm

from vdtutorial.baselines import BASELINES, LinearFeatureBaseline, Obs, default_baseline_features
from vdtutorial.policy import map_obs, obs_to_tensor, on_device, stack_obs, torch_device
from vdtutorial.rollout import Rollout, check_vec_env, iteration_seeds, rollout
from vdtutorial.trust_region import (
    FisherProduct,
    conjugate_gradient,
    double_backward_fvp,
    flat_grad,
    line_search,
    mean_kl,
)

TensorObs = torch.Tensor | dict[str, torch.Tensor]
#: The columns of a log row that measure time rather than learning (:meth:`TRPO.iterate`): seconds, named as such
#: (``_s``, ``_time``), which is how :mod:`vdtutorial.runner.rows` knows to store them coarsely.
TIMING_COLUMNS = ("collect_s", "update_s", "wall_time")
#: The statistics an update returns (:meth:`TRPO.update`), also those a ``TRPO(step=...)`` must return.
STEP_STATS = ("mean_kl", "entropy", "surrogate_improvement", "line_search")


# -- Hyperparameters -----------------------------------------------------------------------------------------
@dataclass
class TRPOConfig:
    """TRPO hyperparameters. ``steps_per_iter`` is the paper's; the paper reports no others, so
    ``max_kl``, ``cg_iters`` and ``fvp_subsample`` are rllab's defaults and the rest are common
    choices (docs/differences.md, "TRPO").

    steps_per_iter: environment steps per iteration, summed over the sub-environments (a multiple of their
        number). The paper's 200 over a 25-step horizon is 8 trajectories per batch.
    gamma: discount factor. Over 25 steps 0.99 keeps 0.99^25 = 0.78 of the final success bonus.
    gae_lambda: GAE's lambda, trading bias (0: one-step TD) against variance (1: Monte-Carlo returns).
    max_kl: delta, the trust-region radius: the largest mean KL(pi_old || pi_new) an accepted step may have.
    cg_iters: conjugate-gradient iterations approximating F^-1 g without ever building F.
    fvp_subsample: the fraction of the batch (a random subset drawn from the iteration's seed) on which the
        Fisher-vector products are computed (g, the step size and the line search use the whole batch). 1.0 is
        rllab's default since its second release; less is a speed option (docs/differences.md, "TRPO's Fisher").
    cg_damping: added to F so that CG works on a positive-definite matrix even where F is singular (along
        pruned weights, or with fewer samples than parameters).
    backtrack_iters, backtrack_coeff: how many step sizes the line search tries, and the factor between them.
    baseline_reg: ridge coefficient of the linear baseline's fit (rllab's value; x10 up to 5 times if the
        solve is not finite).
    baseline: ``"linear"`` (the paper's, rllab's :class:`LinearFeatureBaseline`) or ``"mlp"``, a value network
        fitted by Adam each iteration as in sb3-contrib, given as ``TRPO(baseline=...)``
        (:mod:`vdtutorial.beyond.value_baseline`); ``critic_*``: its widths, learning rate, epochs, minibatch.
    bootstrap_time_limits: at an episode end caused by a time limit, count gamma * V(final observation)
        instead of 0. False is rllab's (the paper's): the horizon is part of the task. True is sb3's.
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
            raise ValueError(
                f"critic_epochs and critic_batch_size must be positive, got "
                f"{self.critic_epochs} and {self.critic_batch_size}"
            )
        self.critic_hidden = tuple(self.critic_hidden)


# -- Advantages ----------------------------------------------------------------------------------------------
def gae(
    rewards: np.ndarray, values: np.ndarray, last_values: np.ndarray, dones: np.ndarray, gamma: float, lam: float
) -> np.ndarray:
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
    next_value = last_values
    next_advantage = 0.0
    for t in reversed(range(len(rewards))):
        alive = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * alive - values[t]
        next_advantage = delta + gamma * lam * alive * next_advantage
        advantages[t] = next_advantage
        next_value = values[t]
    return advantages


# -- 2. advantages: the second part of TRPO.collect ----------------------------------------------------------
def advantages_and_returns(
    trajectories: Rollout,
    features: np.ndarray,
    baseline,
    baseline_features: Callable[[Obs], np.ndarray],
    config: TRPOConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Step 2: the advantages of ``trajectories`` against ``baseline`` (fitted on the previous batch), normalised,
    and the baseline's next targets (``TRPOConfig.baseline``), flat, time-major; ``features`` of the observations.

    Trajectories cut off by the batch end are bootstrapped with V of the observation after them. A
    time-limit end counts as the end of the (finite-horizon) task, value 0 after it, as in rllab; with
    ``bootstrap_time_limits``, gamma * V(final observation) is added to the reward of its last step (the
    episode still ends there: GAE stops at it)."""
    values = baseline.predict(features, trajectories.timesteps).reshape(trajectories.rewards.shape)
    last_values = baseline.predict(baseline_features(trajectories.last_obs), trajectories.last_timesteps)
    rewards = trajectories.rewards.copy()
    if trajectories.time_limit_ends:
        steps, envs, final_obs, final_t = zip(*trajectories.time_limit_ends)
        final_values = baseline.predict(baseline_features(stack_obs(np.stack, final_obs)), np.array(final_t))
        rewards[steps, envs] += config.gamma * final_values
    advantages = gae(rewards, values, last_values, trajectories.dones, config.gamma, config.gae_lambda)
    if config.baseline == "linear":  # rllab: regress on the discounted returns
        returns = gae(rewards, values, last_values, trajectories.dones, config.gamma, 1.0) + values
    else:  # sb3-contrib: regress on the lambda-returns, less noisy targets for a network
        returns = advantages + values
    advantages = advantages.reshape(-1)
    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    return advantages, returns.reshape(-1)


@dataclass
class Batch:
    """One iteration's data, flattened over (time, environment) in time-major order."""

    obs: TensorObs  # (n, ...) policy inputs
    actions: torch.Tensor  # (n, action_dim) the sampled (unclipped) actions
    advantages: torch.Tensor  # (n,) normalised GAE advantages
    features: np.ndarray  # (n, k) baseline features of the observations
    timesteps: np.ndarray  # (n,) step index within the episode
    returns: np.ndarray  # (n,) the baseline's regression targets (see TRPOConfig.baseline)
    episode_returns: list[float]  # undiscounted returns of the episodes that ended in the batch
    successes: int  # how many of those ended with info["is_success"] True
    fvp_index: torch.Tensor | None = None  # (m,) the samples of the Fisher-vector products; None = all

    def to(self, device: torch.device) -> "Batch":
        """A copy with the policy update's tensors on ``device`` (the baseline's numpy arrays stay)."""
        index = None if self.fvp_index is None else self.fvp_index.to(device)
        return replace(
            self,
            obs=obs_to_tensor(self.obs, device),
            actions=self.actions.to(device),
            advantages=self.advantages.to(device),
            fvp_index=index,
        )


def _check_deterministic(policy: nn.Module, obs: TensorObs) -> bool:
    """TRPO's KL(old, new) must be 0 before the step, so ``distribution(obs)`` must be a function of (obs, parameters);
    a sparse-VD policy in training mode draws new weight noise on every call and breaks this silently."""
    with torch.no_grad():
        first = policy.distribution(obs)
        second = policy.distribution(obs)
    if not (torch.equal(first.mean, second.mean) and torch.equal(first.stddev, second.stddev)):
        raise ValueError(
            "TRPO needs a deterministic policy: two evaluations on the same observations differ "
            "(a sparse-VD policy in training mode samples weight noise: call prune_() or eval() first)"
        )
    return True


# -- The algorithm -------------------------------------------------------------------------------------------
class TRPO:
    """TRPO on a gymnasium vector environment.

    policy: the nn.Module to train; ``distribution(obs)``, a diagonal Normal for a float32 tensor (B, d) or a dict of
        them (log-probabilities summed over the last dimension), a deterministic function of (obs, parameters).
    env: a vector environment with ``AutoresetMode.SAME_STEP`` (see :func:`make_vec_env`) that returns fresh
        observation arrays each step (gymnasium's default ``copy=True``), or a zero-argument function that builds one.
    config: hyperparameters, :class:`TRPOConfig`.
    seed: the run's seed; with the parameters it determines every iteration.
    baseline_features: maps a batch of observations (array or dict of arrays, batch first) to a float array
        (batch, k) of the baseline's features; by default :func:`vdtutorial.baselines.default_baseline_features`.
    baseline: V, with ``predict``, ``fit``, ``state_dict`` and ``load_state_dict``; by default rllab's linear one.
    fvp: step 4's Fisher-vector product (default :func:`vdtutorial.trust_region.double_backward_fvp`, any policy);
        an exact one changes the cost only (experiments: :func:`vdtutorial.fast.fisher.gauss_newton_fvp`).
    device: where :meth:`update` runs ("cuda": a GPU); rollouts, the baseline and checkpoints stay on the CPU.
    step: ``step(policy, params, obs, actions, advantages, config) -> dict``, the learner's steps 3-6 (parameters
        left at the new point, :data:`STEP_STATS` returned); chapter 06b drives TRPO with the learner's update through
        it.
    """

    def __init__(
        self,
        policy: nn.Module,
        env: gymnasium.vector.VectorEnv | Callable[[], gymnasium.vector.VectorEnv],
        config: TRPOConfig | None = None,
        seed: int = 0,
        baseline_features: Callable[[Obs], np.ndarray] | None = None,
        baseline=None,
        fvp: FisherProduct = double_backward_fvp,
        device: torch.device | str = "cpu",
        step: Callable[..., dict] | None = None,
    ):
        self.policy = policy
        self.fvp = fvp
        self.device = torch_device(device)
        self.step = step
        self.env = env if isinstance(env, gymnasium.vector.VectorEnv) else env()
        self.config = config or TRPOConfig()
        self.seed = seed
        self.baseline_features = baseline_features or default_baseline_features
        if baseline is None and self.config.baseline != "linear":
            raise ValueError(
                f"config.baseline={self.config.baseline!r} is a value network: pass TRPO(baseline="
                "vdtutorial.beyond.value_baseline.value_baseline(config, env, seed))"
            )
        self.baseline = LinearFeatureBaseline(self.config.baseline_reg) if baseline is None else baseline
        self.params = [p for p in policy.parameters() if p.requires_grad]
        self.iteration_index = 0
        self.rows: list[dict] = []
        self.checked_deterministic = False  # by the first update (see _check_deterministic)
        check_vec_env(self.env, self.config.steps_per_iter)

    # -- 1. collect, 2. advantages ----------------------------------------------------------------
    def collect(self) -> Batch:
        """One batch of the current policy (:func:`rollout`) and its advantages, seeded by (seed, iteration_index)."""
        cfg = self.config
        n = self.env.num_envs
        env_seeds, noise_seed = iteration_seeds(self.seed, self.iteration_index, n)
        generator = torch.Generator().manual_seed(noise_seed)
        steps_per_env = cfg.steps_per_iter // n
        trajectories = rollout(self.policy, self.env, steps_per_env, env_seeds, generator, cfg.bootstrap_time_limits)
        features = self.baseline_features(trajectories.observations)
        advantages, returns = advantages_and_returns(trajectories, features, self.baseline, self.baseline_features, cfg)
        fvp_index = None
        if cfg.fvp_subsample < 1.0:  # drawn after the actions, so the rollouts do not depend on it
            size = max(1, int(cfg.steps_per_iter * cfg.fvp_subsample))
            fvp_index = torch.randperm(cfg.steps_per_iter, generator=generator)[:size]
        return Batch(
            obs=obs_to_tensor(trajectories.observations),
            actions=trajectories.actions,
            advantages=torch.as_tensor(advantages, dtype=torch.float32),
            features=features,
            timesteps=trajectories.timesteps,
            returns=returns,
            episode_returns=trajectories.episode_returns,
            successes=trajectories.successes,
            fvp_index=fvp_index,
        )

    # -- 3-7. the update --------------------------------------------------------------------------
    def update(self, batch: Batch) -> dict:
        """Steps 3-6 on ``batch``, then refit the baseline (step 7). Returns :data:`STEP_STATS`: mean KL, entropy before
        the step, surrogate improvement, line search (accepted fraction or "rejected"). The first update checks that
        the policy is deterministic (ValueError if not)."""
        if not self.checked_deterministic:
            self.checked_deterministic = _check_deterministic(self.policy, map_obs(lambda x: x[:8], batch.obs))
        with on_device(self.policy, self.device):
            return self._step(batch.to(self.device))

    def _step(self, batch: Batch) -> dict:
        if self.step is None:
            stats = self._trpo_step(batch, self.config)
        else:  # the learner's steps 3-6
            stats = self.step(self.policy, self.params, batch.obs, batch.actions, batch.advantages, self.config)
            if not isinstance(stats, dict) or not set(STEP_STATS) <= set(stats):
                raise TypeError(f"TRPO(step=...) must return a dict with the keys {STEP_STATS}, got {stats!r}")
        self.baseline.fit(batch.features, batch.timesteps, batch.returns)
        return {key: stats[key] for key in STEP_STATS}

    def _trpo_step(self, batch: Batch, cfg: TRPOConfig) -> dict:
        obs = batch.obs
        dist = self.policy.distribution(obs)  # one forward with graph at theta_old: pi_old (detached), surrogate, g
        old = Normal(dist.mean.detach().clone(), dist.stddev.detach().clone())
        old_log_prob = old.log_prob(batch.actions).sum(-1)

        def surrogate_of(dist: Normal) -> torch.Tensor:
            ratio = torch.exp(dist.log_prob(batch.actions).sum(-1) - old_log_prob)
            return (ratio * batch.advantages).mean()

        def surrogate_and_kl() -> tuple[torch.Tensor, torch.Tensor]:
            dist = self.policy.distribution(obs)
            return surrogate_of(dist), mean_kl(old, dist)

        surrogate = surrogate_of(dist)
        index = batch.fvp_index
        g = flat_grad(surrogate, self.params, retain_graph=index is None)  # the double backward may reuse the graph
        if index is None:  # F over the whole batch, at the forward pass just made
            Fvp = self.fvp(self.policy, self.params, obs, old, cfg.cg_damping, dist)
        else:  # F over the subsample (TRPOConfig.fvp_subsample)
            sub_obs = map_obs(lambda x: x[index], obs)
            sub_old = Normal(old.mean[index], old.stddev[index])
            Fvp = self.fvp(self.policy, self.params, sub_obs, sub_old, cfg.cg_damping)
        direction = conjugate_gradient(Fvp, g, cfg.cg_iters)
        sFs = (direction @ Fvp(direction)).item()
        # Scale so that the KL's quadratic model, 0.5 step^T F step, is max_kl (a zero gradient: a zero step, rejected).
        if sFs > 0:
            full_step = math.sqrt(2 * cfg.max_kl / sFs) * direction
        else:
            full_step = torch.zeros_like(direction)
        fraction, improvement, kl = line_search(
            self.params,
            full_step,
            surrogate_and_kl,
            cfg.max_kl,
            cfg.backtrack_iters,
            cfg.backtrack_coeff,
            surrogate.item(),
        )
        return {
            "mean_kl": kl,
            "entropy": old.entropy().sum(-1).mean().item(),
            "surrogate_improvement": improvement,
            "line_search": "rejected" if fraction is None else fraction,
        }

    # -- one iteration, the main loop ---------------------------------------------------------------
    def iterate(self) -> dict:
        """One iteration: collect, update, advance ``iteration_index``. Returns its log row (also appended to
        ``rows``): counts, the update's statistics and the :data:`TIMING_COLUMNS` (collecting, updating, run so far)."""
        start = time.perf_counter()
        batch = self.collect()
        collected = time.perf_counter()
        stats = self.update(batch)
        updated = time.perf_counter()
        previous_time = self.rows[-1]["wall_time"] if self.rows else 0.0
        row = {
            "iteration": self.iteration_index,
            "env_steps": (self.iteration_index + 1) * self.config.steps_per_iter,
            "successes": batch.successes,
            "episodes": len(batch.episode_returns),
            "mean_return": float(np.mean(batch.episode_returns)) if batch.episode_returns else math.nan,
            **stats,
            "collect_s": collected - start,
            "update_s": updated - collected,
            "wall_time": previous_time + updated - start,
        }
        self.rows.append(row)
        self.iteration_index += 1
        return row

    def run(
        self,
        total_steps: int,
        csv_path: str | os.PathLike | None = None,
        checkpoint_path: str | os.PathLike | None = None,
        progress: bool = True,
    ) -> list[dict]:
        """Iterate until ``total_steps`` environment steps (counting iterations before a checkpoint) are collected,
        appending each log row to ``csv_path`` and checkpointing to ``checkpoint_path`` when given. Returns all rows."""
        total_iters = math.ceil(total_steps / self.config.steps_per_iter)
        with tqdm(total=total_iters, initial=self.iteration_index, disable=not progress, desc="TRPO") as bar:
            while self.iteration_index < total_iters:
                row = self.iterate()
                if csv_path is not None:
                    _append_csv(csv_path, row)
                if checkpoint_path is not None:
                    self.save(checkpoint_path)
                bar.update()
                bar.set_postfix(mean_return=f"{row['mean_return']:.2f}", successes=row["successes"])
        return self.rows

    # -- checkpoints ------------------------------------------------------------------------------
    def checkpoint(self) -> dict:
        """Policy, baseline, iteration index, log rows: all a run needs to continue (noise comes from (seed,
        iteration))."""
        return {
            "policy": self.policy.state_dict(),
            "baseline": self.baseline.state_dict(),
            "iteration": self.iteration_index,
            "rows": self.rows,
            "seed": self.seed,
            "config": asdict(self.config),
        }

    def restore(self, state: dict) -> None:
        """Continue from a :meth:`checkpoint` of a run with the same seed and config."""
        saved_config = {**asdict(TRPOConfig()), **state["config"]}  # a field added since: its old behaviour
        if state["seed"] != self.seed or saved_config != asdict(self.config):
            raise ValueError(
                "checkpoint was written with a different seed or config: resuming would not continue the run"
            )
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
