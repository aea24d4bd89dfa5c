"""A value network for TRPO's baseline, as sb3-contrib and Spinning Up use: ``TRPOConfig(baseline="mlp")``.

The paper's baseline is rllab's linear one (:mod:`vdtutorial.baselines`). The network is here for the
comparison with sb3-contrib's TRPO at its own best settings (:mod:`vdtutorial.experiments.pendulum`):
``TRPO(policy, env, config, baseline=value_baseline(config, env, seed=seed))``.

Taught in chapter 06b.
"""

from __future__ import annotations

from typing import Callable

import gymnasium
import numpy as np
import torch
from torch import nn

from vdtutorial.baselines import Obs, default_baseline_features
from vdtutorial.trpo import TRPOConfig


class MLPBaseline:
    """State-value network V(s) = MLP(features(s)), fitted by minibatch Adam on each batch.

    The alternative to :class:`~vdtutorial.baselines.LinearFeatureBaseline` that sb3-contrib and Spinning Up use: a tanh
    MLP regressed (mean squared error) on the batch's value targets for ``epochs`` shuffled passes,
    with one Adam optimiser kept over the whole run. It sees the features only, not the time step:
    it is meant to go with ``bootstrap_time_limits``, under which the value of a state does not
    depend on the time left. Its initial weights and the order of its minibatches come from
    ``seed`` (and the number of fits so far), so a run that saves and reloads it (``state_dict``:
    the weights, Adam's moments and the fit count) continues exactly.
    """

    def __init__(
        self,
        num_features: int,
        hidden: tuple[int, ...] = (64, 64),
        lr: float = 1e-3,
        epochs: int = 10,
        batch_size: int = 128,
        seed: int = 0,
    ):
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


def value_baseline(
    config: TRPOConfig,
    env: gymnasium.vector.VectorEnv,
    seed: int,
    features: Callable[[Obs], np.ndarray] = default_baseline_features,
) -> MLPBaseline:
    """The network that ``config``'s ``critic_*`` settings describe, for TRPO's ``baseline=``; its input width
    comes from the features of a sample of the (batched) observation space."""
    num_features = features(env.observation_space.sample()).shape[1]
    return MLPBaseline(
        num_features, config.critic_hidden, config.critic_lr, config.critic_epochs, config.critic_batch_size, seed=seed
    )
