"""The optional value-network baseline of vdtutorial.baselines and bootstrapping at time limits; the
default (rllab's linear baseline, value 0 after every episode end) is covered by test_trpo.py."""

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium import spaces

from vdtutorial.beyond.value_baseline import MLPBaseline, value_baseline
from vdtutorial.rollout import make_vec_env
from vdtutorial.trpo import TIMING_COLUMNS, TRPO, TRPOConfig
from test_trpo import LinearPolicy, PointReach

MLP_CONFIG = TRPOConfig(steps_per_iter=40, baseline="mlp", critic_batch_size=16, bootstrap_time_limits=True)


def mlp_trpo(seed: int) -> TRPO:
    env = make_vec_env(lambda: PointReach(), 2)
    return TRPO(LinearPolicy(), env, MLP_CONFIG, seed=seed, baseline=value_baseline(MLP_CONFIG, env, seed))


def test_critic_fits_returns_on_a_toy_batch():
    rng = np.random.default_rng(0)
    features = rng.uniform(-1, 1, (512, 3))
    returns = np.sin(2 * features[:, 0]) + features[:, 1] ** 2 - features[:, 2]  # not linear in the features
    critic = MLPBaseline(3, epochs=150, batch_size=64, seed=0)
    before = np.mean((critic.predict(features, None) - returns) ** 2)
    critic.fit(features, np.zeros(512), returns)
    after = np.mean((critic.predict(features, None) - returns) ** 2)
    assert critic.fits == 1
    assert after < 0.02 * np.var(returns) < before
    # the same seed gives the same network, fit for fit
    twin = MLPBaseline(3, epochs=150, batch_size=64, seed=0)
    twin.fit(features, np.zeros(512), returns)
    np.testing.assert_array_equal(twin.predict(features, None), critic.predict(features, None))


def test_config_validates_the_baseline_fields():
    with pytest.raises(ValueError, match="baseline must be one of"):
        TRPOConfig(baseline="quadratic")
    with pytest.raises(ValueError, match="positive"):
        TRPOConfig(baseline="mlp", critic_epochs=0)


def test_critic_state_survives_save_load_and_the_run_resumes_exactly(tmp_path):
    def fresh(seed_of_init):
        torch.manual_seed(seed_of_init)
        return mlp_trpo(7)

    full = fresh(0)
    full_rows = full.run(4 * 40, progress=False)

    first = fresh(0)
    first.run(2 * 40, checkpoint_path=tmp_path / "ckpt.pt", progress=False)
    second = fresh(123)  # a different policy initialisation, overwritten by the checkpoint
    second.load(tmp_path / "ckpt.pt")
    assert second.baseline.fits == 2
    for a, b in zip(first.baseline.net.parameters(), second.baseline.net.parameters()):
        assert torch.equal(a, b)
    assert (
        second.baseline.optimizer.state_dict()["state"][0]["step"]
        == first.baseline.optimizer.state_dict()["state"][0]["step"]
    )
    second_rows = second.run(4 * 40, progress=False)

    def without_wall_time(rows):
        return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]

    assert without_wall_time(second_rows) == without_wall_time(full_rows)
    for a, b in zip(full.baseline.net.parameters(), second.baseline.net.parameters()):
        assert torch.equal(a, b)


def test_checkpoint_written_before_the_critic_fields_existed_still_loads(tmp_path):
    algo = TRPO(LinearPolicy(), make_vec_env(lambda: PointReach(), 2), TRPOConfig(steps_per_iter=40), seed=1)
    algo.iterate()
    algo.save(tmp_path / "ckpt.pt")
    state = torch.load(tmp_path / "ckpt.pt", weights_only=True)
    for key in (
        "baseline",
        "critic_hidden",
        "critic_lr",
        "critic_epochs",
        "critic_batch_size",
        "bootstrap_time_limits",
    ):
        del state["config"][key]
    torch.save(state, tmp_path / "old.pt")
    resumed = TRPO(LinearPolicy(), make_vec_env(lambda: PointReach(), 2), TRPOConfig(steps_per_iter=40), seed=1)
    resumed.load(tmp_path / "old.pt")
    assert resumed.iteration_index == 1
    with pytest.raises(ValueError, match="different seed or config"):  # but a critic run cannot resume it
        mlp_trpo(1).load(tmp_path / "old.pt")


# ---------------------------------------------------------------------------------------------
# Time limits, on a hand-made batch
# ---------------------------------------------------------------------------------------------
class ThreeSteps(gymnasium.Env):
    """Observation [t] for t = 0, 1, 2, then the final observation [3]; reward 1 per step. The episode
    ends after 3 steps by termination, by truncation (a time limit), or by both at once."""

    observation_space = spaces.Box(-np.inf, np.inf, (1,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, terminated: bool, truncated: bool):
        self.end = (terminated, truncated)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0], np.float32), {}

    def step(self, action):
        self.t += 1
        over = self.t == 3
        return np.array([self.t], np.float32), 1.0, over and self.end[0], over and self.end[1], {}


class KnownValue:
    """A baseline with V(s) = 10 + s, not fitted: the bootstrapped value of the final observation is 13."""

    def predict(self, features, timesteps):
        return 10.0 + features[:, 0]

    def fit(self, features, timesteps, returns):
        pass


@pytest.mark.parametrize("bootstrap", [True, False])
def test_time_limit_bootstrap_uses_v_of_the_final_observation_only_where_truncated(bootstrap):
    ends = [(True, False), (False, True), (True, True)]  # terminated; time limit; both (a termination)
    env = gymnasium.vector.SyncVectorEnv(
        [lambda e=e: ThreeSteps(*e) for e in ends], autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP
    )
    gamma = 0.5
    config = TRPOConfig(steps_per_iter=9, gamma=gamma, gae_lambda=1.0, baseline="mlp", bootstrap_time_limits=bootstrap)
    algo = TRPO(LinearPolicy(), env, config, seed=0, baseline=KnownValue())
    batch = algo.collect()
    # With lambda = 1 the value network's targets A + V are the discounted returns, bootstrapped
    # with gamma * V(final observation) = 0.5 * 13 after a time limit (and with 0 after a termination).
    plain = [1 + gamma + gamma**2, 1 + gamma, 1.0]
    bootstrapped = [1 + gamma + gamma**2 + gamma**3 * 13, 1 + gamma + gamma**2 * 13, 1 + gamma * 13]
    expected = np.array([[plain[t], bootstrapped[t] if bootstrap else plain[t], plain[t]] for t in range(3)])
    np.testing.assert_allclose(batch.returns, expected.reshape(-1))  # time-major: (t, env)
    assert batch.episode_returns == [3.0, 3.0, 3.0]  # the logged returns are the rewards only


def test_a_value_network_config_without_the_network_is_refused_with_where_to_find_it():
    """The core builds only the paper's linear baseline; the network lives beside it (vdtutorial.beyond)."""
    with pytest.raises(ValueError, match=r"is a value network: pass TRPO\(baseline=vdtutorial.beyond.value_baseline"):
        TRPO(LinearPolicy(), make_vec_env(lambda: PointReach(), 2), MLP_CONFIG, seed=0)
    algo = mlp_trpo(0)
    assert (
        isinstance(algo.baseline, MLPBaseline)
        and algo.baseline.net[0].in_features == PointReach().observation_space.shape[0]
    )
