"""The value baseline V(s, t) that TRPO's advantages subtract: rllab's linear feature baseline (the
paper's), with the features it reads. A value network, sb3-contrib's and Spinning Up's choice, is beside
the core: :mod:`vdtutorial.beyond.value_baseline`.

It is fitted on one batch and predicts on the next, so the advantages of a batch never use a baseline that
has seen their own returns. Its state is in ``state_dict``, so a checkpointed run continues exactly.

Taught in chapter 06b.
"""

from __future__ import annotations

import numpy as np
import torch

#: A batch of observations, batch first: an array, or a dict of arrays (image + joints).
Obs = np.ndarray | dict[str, np.ndarray]
#: The baselines TRPOConfig.baseline can name: rllab's linear one and a value network.
BASELINES = ("linear", "mlp")


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
        return np.concatenate([f, f**2, t, t**2, t**3, np.ones_like(t)], axis=1)

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
