"""The value baselines V(s, t) that TRPO's advantages subtract: rllab's linear feature baseline (the
paper's) and a value network (sb3-contrib's and Spinning Up's choice), with the features they read.

Chapter 06, section 4 teaches the linear one; the benchmark of section 7 uses the network. Either is
fitted on one batch and predicts on the next, so the advantages of a batch never use a baseline that
has seen their own returns. Both keep all their state in ``state_dict``, so a checkpointed run
continues exactly.

Taught in chapter 06b.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

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
