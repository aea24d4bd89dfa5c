"""DART for the IK expert: learn the demonstration noise from the cloned policy's own errors.

The paper injects Gaussian noise of a hand-set standard deviation Sigma into the expert's executed
actions (eq. 6) and shows (Fig. 6) that the choice matters. DART (Laskey, Lee, Fox, Dragan, Goldberg,
"DART: Noise Injection for Robust Imitation Learning", CoRL 2017, arXiv:1703.09327; the paper's ref. [15])
chooses the noise instead: the supervisor should be disturbed the way the learner will err, so that the
demonstrations visit the states the learner will drift into. For Gaussian noise their noise optimisation
has a closed form (Section 5 of their paper, "optimizing for Gaussian noise"): the covariance of the
learner's error along the supervisor's trajectories,

    Sigma_hat = (1/T) E_{xi ~ p(xi | pi_exp, Sigma_k)} [ sum_t (pi_theta(x_t) - pi_exp(x_t)) (pi_theta(x_t) -
    pi_exp(x_t))^T ],

i.e. the mean outer product of the error per visited state (not centred: a learner that errs always the
same way must be disturbed that way too). They also give a scaled variant, Sigma_alpha = alpha /
(T tr(Sigma_hat)) Sigma_hat, that sets the total error to a prior alpha when the learner is expected to be
worse at test time than on the training states.

Taught in chapter 09.
"""

from __future__ import annotations

import numpy as np
import torch

from vdtutorial.demos import Demos
from vdtutorial.envs.scene import N_JOINTS
from vdtutorial.beyond.imitation_rounds import RoundsResult, cloning_config, run_rounds
from vdtutorial.policy import GaussianPolicy
from vdtutorial.pretrain import PretrainConfig, split_by_episode

#: Added to the diagonal before the Cholesky factorisation of a covariance: an estimate from fewer states
#: than joints, or a joint the learner never gets wrong, is only positive semi-definite.
JITTER = 1e-10


def noise_estimate(errors: np.ndarray, alpha: float | None = None, horizon: int | None = None) -> np.ndarray:
    """DART's Gaussian noise from the learner's errors ``errors`` (one row pi_theta(x) - pi_exp(x) per
    visited state): their mean outer product Sigma_hat; with ``alpha`` (and the horizon T) the scaled
    Sigma_alpha = alpha / (T tr(Sigma_hat)) Sigma_hat (module docstring, "a scaled variant").

    **The variant implemented here** is the unscaled closed form Sigma_hat (:func:`noise_estimate`; pass
    ``alpha`` and ``horizon`` for Sigma_alpha). The expectation is taken over the *held-out* episodes of the
    aggregated demonstrations (the whole episodes that pre-training did not fit,
    :func:`vdtutorial.pretrain.split_by_episode`):
    they are supervisor trajectories under the current noise that the policy has not been trained on, which is
    what the expectation asks for; on its own training states the error would be underestimated. The labels
    pi_exp(x_t) are the ones already stored with those states, so the estimate costs no expert query.
    """
    errors = np.asarray(errors, dtype=np.float64)
    if errors.ndim != 2 or len(errors) == 0:
        raise ValueError(f"errors must be a non-empty (states, action dims) array, got shape {errors.shape}")
    sigma_hat = errors.T @ errors / len(errors)
    if alpha is None:
        return sigma_hat
    if horizon is None or horizon < 1:
        raise ValueError("the scaled variant needs the horizon T")
    return alpha / (horizon * np.trace(sigma_hat)) * sigma_hat


@torch.no_grad()
def policy_errors(policy: GaussianPolicy, demos: Demos, indices=None) -> np.ndarray:
    """pi_theta(x) - pi_exp(x) on the states ``indices`` of ``demos`` (default all): the mean action in eval
    mode (sparse VD: weights with log alpha > 3 dropped) minus the stored expert label."""
    idx = np.arange(len(demos)) if indices is None else np.asarray(indices)
    was_training = policy.training
    policy.eval()
    mean = policy.act(demos.states[idx], deterministic=True)
    policy.train(was_training)
    return mean - demos.actions[idx]


def estimate_noise(policy: GaussianPolicy, demos: Demos, config: PretrainConfig, seed: int) -> np.ndarray:
    """Sigma_hat of ``policy`` over the held-out episodes of ``demos`` (the split of pre-training with
    ``config.val_fraction`` and ``seed``); over every state when nothing is held out (tiny sets)."""
    _, held_out = split_by_episode(demos, config.val_fraction, seed)
    return noise_estimate(policy_errors(policy, demos, held_out if len(held_out) else None))


def noisy_expert(covariance: np.ndarray):
    """The behaviour of eq. 6 with a full covariance: the expert's action plus N(0, covariance)."""
    factor = np.linalg.cholesky(np.asarray(covariance, dtype=np.float64) + JITTER * np.eye(len(covariance)))
    return lambda state, a_exp, rng: a_exp + factor @ rng.standard_normal(len(a_exp))


def sigma_per_joint(covariance: np.ndarray) -> np.ndarray:
    """The standard deviation per joint of a covariance (its diagonal's root): comparable with a hand-set Sigma."""
    return np.sqrt(np.diag(np.asarray(covariance, dtype=np.float64)))


def dart(
    task: str = "reach",
    reg: str = "vd",
    samples: int = 8000,
    rounds: int = 4,
    start_sigma: float = 0.05,
    seed: int = 0,
    config: PretrainConfig | None = None,
    progress: bool = False,
) -> RoundsResult:
    """DART's rounds (module docstring, "chooses the noise instead") from Sigma_0 = ``start_sigma``^2 I, cloning with
    ``reg``.

    Each round's record holds the covariance it collected with and its per-joint standard deviation; the
    last one also holds ``next_covariance`` (and ``next_sigma_per_joint``), the estimate from the final
    policy: the noise DART would use next, the learned Sigma.

    **Rounds** (DART's Algorithm 1, with :mod:`vdtutorial.beyond.imitation_rounds`): round 0 collects with a start
    Sigma_0 = sigma_0^2 I (a poorly chosen hand-set value), then each round clones the expert on everything
    collected so far and sets the next round's covariance to Sigma_hat of that policy. The number of labels
    is fixed per round (the experiment's 8000 split over the rounds), so DART spends exactly the labels of a
    one-shot data set.
    """
    if not np.isfinite(start_sigma) or start_sigma < 0:
        raise ValueError(f"start_sigma must be a finite standard deviation >= 0, got {start_sigma!r}")
    cfg = cloning_config(reg, config)

    def plan(k, policy, demos):
        covariance = start_sigma**2 * np.eye(N_JOINTS) if policy is None else estimate_noise(policy, demos, cfg, seed)
        return noisy_expert(covariance), {
            "covariance": covariance.tolist(),
            "sigma_per_joint": sigma_per_joint(covariance).tolist(),
        }

    result = run_rounds("dart", task, reg, samples, rounds, seed, plan, cfg, progress)
    learned = estimate_noise(result.policy, result.demos, cfg, seed)
    result.rounds[-1]["next_covariance"] = learned.tolist()
    result.rounds[-1]["next_sigma_per_joint"] = sigma_per_joint(learned).tolist()
    return result
