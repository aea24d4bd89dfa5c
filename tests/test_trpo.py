"""Tests of vdtutorial.trpo and vdtutorial.trust_region: each piece against a hand or brute-force computation, then the
whole algorithm on a tiny 1-D reaching task defined here."""

import copy
import math
import time

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium import spaces
from torch import nn
from torch.distributions import Normal, kl_divergence

from vdtutorial.experiments.pendulum import pendulum_policy
from vdtutorial.policy import make_policy, obs_to_tensor
from vdtutorial.rollout import iteration_seeds, make_vec_env
from vdtutorial.trpo import TIMING_COLUMNS, TRPO, TRPOConfig, gae
from vdtutorial.trust_region import (
    conjugate_gradient,
    double_backward_fvp,
    fisher_vector_product,
    flat_grad,
    line_search,
    mean_kl,
)


# ---------------------------------------------------------------------------------------------
# A tiny task and tiny policies
# ---------------------------------------------------------------------------------------------
class PointReach(gymnasium.Env):
    """Move a point on a line to 0: x' = x + 0.2 a, reward -|x'|, success if |x| < 0.1 at the end
    of the 10-step horizon. With dict=True the observation is {"joints": x, "image": 2x2 array}."""

    def __init__(self, dict_obs: bool = False):
        self.dict_obs = dict_obs
        box = spaces.Box(-np.inf, np.inf, (1,), np.float32)
        self.observation_space = (
            spaces.Dict({"joints": box, "image": spaces.Box(0, 1, (2, 2), np.float32)}) if dict_obs else box
        )
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def _obs(self):
        x = np.array([self.x], dtype=np.float32)
        return {"joints": x, "image": np.full((2, 2), self.x, np.float32)} if self.dict_obs else x

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.t = self.np_random.uniform(-1, 1), 0
        return self._obs(), {}

    def step(self, action):
        self.x += 0.2 * float(action[0])
        self.t += 1
        end = self.t == 10
        info = {"is_success": np.bool_(abs(self.x) < 0.1)} if end else {}
        return self._obs(), -abs(self.x), False, end, info


class LinearPolicy(nn.Module):
    def __init__(self, obs_dim=1, act_dim=1, dtype=torch.float32):
        super().__init__()
        self.linear = nn.Linear(obs_dim, act_dim, dtype=dtype)
        self.log_std = nn.Parameter(torch.full((act_dim,), -0.5, dtype=dtype))

    def distribution(self, obs):
        obs = obs["joints"] if isinstance(obs, dict) else obs
        mean = self.linear(obs.to(self.linear.weight.dtype))
        return Normal(mean, self.log_std.exp().expand_as(mean))


class MaskedPolicy(nn.Module):
    """A linear layer whose weight is multiplied by a fixed 0/1 mask (a pruned layer), plus a
    frozen parameter that stands for variational dropout's log sigma^2."""

    def __init__(self):
        super().__init__()
        self.weight = nn.Parameter(torch.tensor([[0.3, 0.0, -0.2, 0.0]]))
        self.register_buffer("mask", torch.tensor([[1.0, 0.0, 1.0, 0.0]]))
        self.log_sigma2 = nn.Parameter(torch.full((1, 4), -4.0), requires_grad=False)
        self.log_std = nn.Parameter(torch.zeros(1))

    def distribution(self, obs):
        features = torch.cat([obs, obs**2, torch.sin(3 * obs), torch.ones_like(obs)], dim=-1)
        mean = features @ (self.weight * self.mask).T
        return Normal(mean, self.log_std.exp().expand_as(mean))


def make_env(num_envs=2, dict_obs=False):
    return make_vec_env(lambda: PointReach(dict_obs), num_envs)


# ---------------------------------------------------------------------------------------------
# The pieces
# ---------------------------------------------------------------------------------------------
def test_conjugate_gradient_solves_spd_system():
    rng = np.random.default_rng(0)
    M = rng.normal(size=(6, 6))
    A = M @ M.T + 0.5 * np.eye(6)
    b = rng.normal(size=6)
    A_t, b_t = torch.tensor(A), torch.tensor(b)
    x = conjugate_gradient(lambda v: A_t @ v, b_t, iters=20)
    np.testing.assert_allclose(x.numpy(), np.linalg.solve(A, b), rtol=1e-8, atol=1e-10)


def test_fisher_vector_product_matches_explicit_fisher():
    torch.manual_seed(0)
    policy = LinearPolicy(obs_dim=2, act_dim=1, dtype=torch.float64)  # 4 parameters
    params = list(policy.parameters())
    obs = torch.randn(50, 2, dtype=torch.float64)
    with torch.no_grad():
        old = policy.distribution(obs)
        old = Normal(old.mean.clone(), old.stddev.clone())
    theta0 = torch.cat([p.reshape(-1) for p in params]).detach()

    def mean_kl_at(theta):  # the same policy as a function of the flat vector (log_std, weight, bias)
        log_std, w, b = theta[0], theta[1:3], theta[3]
        mean = (obs @ w + b).unsqueeze(-1)
        return kl_divergence(old, Normal(mean, log_std.exp().expand_as(mean))).sum(-1).mean()

    fisher = torch.autograd.functional.hessian(mean_kl_at, theta0)
    # Second definition of the Fisher matrix: E[grad log pi grad log pi^T] for a ~ pi_old(.|s).
    # For a Gaussian with a linear mean it has the closed form below (per sample):
    #   d/d(w,b) log pi = (a - mu) / sigma^2 * [s, 1],  d/d log_std log pi = (a - mu)^2 / sigma^2 - 1
    sigma2 = old.stddev.pow(2).squeeze(-1)
    x = torch.cat([obs, torch.ones(50, 1, dtype=torch.float64)], dim=1)
    expected = torch.zeros(4, 4, dtype=torch.float64)
    expected[0, 0] = 2.0
    expected[1:, 1:] = (x.T * (1 / sigma2)) @ x / 50
    torch.testing.assert_close(fisher, expected)

    kl_grad = flat_grad(kl_divergence(old, policy.distribution(obs)).sum(-1).mean(), params, create_graph=True)
    for seed in range(3):
        v = torch.randn(4, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        torch.testing.assert_close(fisher_vector_product(kl_grad, params, v, damping=0.1), fisher @ v + 0.1 * v)


def test_gae_against_hand_computation():
    gamma, lam = 0.9, 0.5
    rewards = np.array([1.0, 2.0, 3.0, 4.0])
    values = np.array([0.5, 1.0, 1.5, 2.0])
    dones = np.array([0.0, 1.0, 0.0, 0.0])  # the episode ends with step 1; steps 2-3 are cut off
    last_value = 10.0
    d3 = 4 + 0.9 * 10.0 - 2.0  # bootstrapped with the baseline after the cut
    d2 = 3 + 0.9 * 2.0 - 1.5
    d1 = 2 + 0.0 - 1.0  # terminal: no value after it
    d0 = 1 + 0.9 * 1.0 - 0.5
    expected = [d0 + 0.45 * d1, d1, d2 + 0.45 * d3, d3]
    np.testing.assert_allclose(gae(rewards, values, np.array(last_value), dones, gamma, lam), expected)
    # lam = 1 gives the discounted returns minus the values
    returns = gae(rewards, values, np.array(last_value), dones, gamma, 1.0) + values
    np.testing.assert_allclose(returns, [1 + 0.9 * 2, 2, 3 + 0.9 * 4 + 0.81 * 10, 4 + 0.9 * 10])
    # (T, N): columns are independent environments
    two = gae(
        np.stack([rewards, rewards], 1),
        np.stack([values, values], 1),
        np.array([10.0, 10.0]),
        np.stack([dones, dones], 1),
        gamma,
        lam,
    )
    np.testing.assert_allclose(two[:, 1], expected)


def test_line_search_restores_parameters_when_no_step_is_acceptable():
    p = nn.Parameter(torch.tensor([1.0, 2.0]))
    fraction, improvement, kl = line_search([p], torch.tensor([1.0, 1.0]), lambda: (-p.sum(), p.sum() * 0), max_kl=0.01)
    assert fraction is None and improvement == 0.0 and kl == 0.0
    assert p.tolist() == [1.0, 2.0]
    # accepts the first fraction (1, 0.5, 0.25, ...) whose KL is within the bound
    fraction, improvement, kl = line_search(
        [p], torch.tensor([1.0, 1.0]), lambda: (p.sum(), (p - torch.tensor([1.0, 2.0])).pow(2).sum()), max_kl=0.2
    )
    assert fraction == 0.25 and kl == pytest.approx(0.125) and improvement == pytest.approx(0.5)
    assert p.tolist() == [1.25, 2.25]


# ---------------------------------------------------------------------------------------------
# The algorithm
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fvp_subsample", [1.0, 0.25])
def test_accepted_steps_stay_within_the_kl_bound(fvp_subsample):
    torch.manual_seed(0)
    policy = LinearPolicy()
    config = TRPOConfig(steps_per_iter=40, max_kl=0.005, fvp_subsample=fvp_subsample)
    algo = TRPO(policy, make_env(), config, seed=1)
    accepted = 0
    for _ in range(6):
        batch = algo.collect()
        old = copy.deepcopy(policy)
        stats = algo.update(batch)
        algo.iteration_index += 1
        with torch.no_grad():
            kl = kl_divergence(old.distribution(batch.obs), policy.distribution(batch.obs)).sum(-1).mean().item()
        assert kl == pytest.approx(stats["mean_kl"], abs=1e-7)
        assert kl <= config.max_kl + 1e-7
        if stats["line_search"] != "rejected":
            accepted += 1
            assert stats["surrogate_improvement"] > 0 and kl > 0
    assert accepted >= 4


@pytest.mark.parametrize("fvp_subsample", [1.0, 0.25])
def test_step_is_the_natural_gradient_with_fisher_on_the_subsample(fvp_subsample):
    """The update's full step, rebuilt by hand: g from the whole batch, F explicitly from the
    samples in batch.fvp_index (all of them for fvp_subsample=1), s = (F + damping I)^-1 g,
    scaled to a quadratic-model KL of max_kl."""
    torch.manual_seed(0)
    policy = LinearPolicy(dtype=torch.float64)
    config = TRPOConfig(steps_per_iter=40, fvp_subsample=fvp_subsample)
    algo = TRPO(policy, make_env(), config, seed=2)
    batch = algo.collect()
    index = torch.arange(40) if fvp_subsample == 1.0 else batch.fvp_index
    assert len(index) == int(40 * fvp_subsample) and len(set(index.tolist())) == len(index)
    params = algo.params
    theta_old = torch.cat([p.detach().reshape(-1) for p in params]).clone()
    with torch.no_grad():
        old = policy.distribution(batch.obs)
    dist = policy.distribution(batch.obs)
    ratio = torch.exp(dist.log_prob(batch.actions).sum(-1) - old.log_prob(batch.actions).sum(-1))
    g = flat_grad((ratio * batch.advantages.double()).mean(), params)
    sub_old = Normal(old.mean[index], old.stddev[index])
    fisher = torch.autograd.functional.hessian(lambda flat: _kl_at(policy, flat, batch.obs[index], sub_old), theta_old)
    damped = fisher + config.cg_damping * torch.eye(len(g), dtype=g.dtype)
    direction = torch.linalg.solve(damped, g)  # CG is exact here: 3 parameters, 10 iterations
    full_step = direction * np.sqrt(2 * config.max_kl / (direction @ damped @ direction).item())

    stats = algo.update(batch)
    assert stats["line_search"] != "rejected"
    theta_new = torch.cat([p.detach().reshape(-1) for p in params])
    torch.testing.assert_close((theta_new - theta_old) / stats["line_search"], full_step, rtol=1e-5, atol=1e-8)


def _kl_at(policy, flat, obs, old):
    """Mean KL(old || policy with its parameters replaced by ``flat``), differentiable in ``flat``."""
    log_std, weight, bias = flat[:1], flat[1:2].view(1, 1), flat[2:3]  # policy.parameters() order
    mean = obs.double() @ weight.T + bias
    return kl_divergence(old, Normal(mean, log_std.exp().expand_as(mean))).sum(-1).mean()


def test_fvp_subsample_is_seeded_after_the_rollout_and_validated():
    batches = {}
    for f in (1.0, 0.25):
        torch.manual_seed(0)
        algo = TRPO(LinearPolicy(), make_env(), TRPOConfig(steps_per_iter=40, fvp_subsample=f), seed=4)
        batches[f] = [algo.collect()]
        algo.iteration_index += 1
        batches[f].append(algo.collect())
    for full, sub in zip(batches[1.0], batches[0.25]):  # the subsample does not change the rollouts
        assert full.fvp_index is None
        assert torch.equal(full.actions, sub.actions) and torch.equal(full.obs, sub.obs)
    assert not torch.equal(batches[0.25][0].fvp_index, batches[0.25][1].fvp_index)  # redrawn per iteration
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="fvp_subsample"):
            TRPOConfig(fvp_subsample=bad)


def test_iterate_advances_the_iteration_and_logs_its_times():
    torch.manual_seed(0)
    algo = TRPO(LinearPolicy(), make_env(), TRPOConfig(steps_per_iter=40), seed=0)
    rows = [algo.iterate() for _ in range(3)]
    assert algo.iteration_index == 3 and algo.rows == rows
    assert [(r["iteration"], r["env_steps"]) for r in rows] == [(0, 40), (1, 80), (2, 120)]
    assert list(rows[0])[-len(TIMING_COLUMNS) :] == list(TIMING_COLUMNS)
    assert all(r["collect_s"] > 0 and r["update_s"] > 0 for r in rows)
    # wall_time adds up the iterations: each one's collect and update seconds
    assert rows[-1]["wall_time"] == pytest.approx(sum(r["collect_s"] + r["update_s"] for r in rows), rel=1e-9)


def test_pruned_weights_stay_exactly_zero_and_frozen_parameters_fixed():
    torch.manual_seed(0)
    policy = MaskedPolicy()
    frozen = policy.log_sigma2.detach().clone()
    weight_before = policy.weight.detach().clone()
    algo = TRPO(policy, make_env(), TRPOConfig(steps_per_iter=40), seed=0)
    assert algo.params == [policy.weight, policy.log_std]
    rows = [algo.iterate() for _ in range(4)]
    assert any(r["line_search"] != "rejected" for r in rows)
    w = policy.weight.detach()
    assert torch.all(w[policy.mask == 0] == 0)
    assert not torch.equal(w[policy.mask == 1], weight_before[policy.mask == 1])  # the live weights moved
    assert torch.equal(policy.log_sigma2, frozen)


def test_a_policy_that_samples_weight_noise_is_refused_at_the_first_update():
    """A sparse-VD policy in training mode draws new weights on every call, so KL(old, new) != 0 before the step."""
    box = spaces.Box(-1.0, 1.0, (1,), np.float32)
    torch.manual_seed(0)
    noisy = make_policy(box, 1, variational=True, kind="mlp").train()
    with pytest.raises(ValueError, match="deterministic policy"):
        TRPO(noisy, make_env(), TRPOConfig(steps_per_iter=40), seed=0).iterate()
    row = TRPO(noisy.eval(), make_env(), TRPOConfig(steps_per_iter=40), seed=0).iterate()
    assert np.isfinite(row["mean_kl"])


def test_success_and_episode_accounting():
    algo = TRPO(LinearPolicy(), make_env(num_envs=2), TRPOConfig(steps_per_iter=50), seed=3)
    batch = algo.collect()
    # 25 steps per env, 10-step episodes: 2 finished episodes per env, the third one cut off
    assert len(batch.episode_returns) == 4
    assert 0 <= batch.successes <= 4
    # replay the same (seeded) iteration by hand and count the successes
    env = make_env(num_envs=2)
    env_seeds, noise_seed = iteration_seeds(3, 0, 2)
    gen = torch.Generator().manual_seed(noise_seed)
    obs, _ = env.reset(seed=env_seeds)
    successes, returns, running = 0, [], np.zeros(2)
    for _ in range(25):
        with torch.no_grad():
            d = algo.policy.distribution(obs_to_tensor(obs))
            a = d.mean + d.stddev * torch.randn(d.mean.shape, generator=gen)
        obs, r, term, trunc, info = env.step(np.clip(a.numpy(), -1, 1))
        running += r
        for i in np.flatnonzero(term | trunc):
            successes += int(abs(info["final_obs"][i][0]) < 0.1)
            returns.append(running[i])
            running[i] = 0
    assert batch.successes == successes
    np.testing.assert_allclose(sorted(batch.episode_returns), sorted(returns))


def test_rejects_next_step_autoreset():
    env = gymnasium.vector.SyncVectorEnv([PointReach], autoreset_mode=gymnasium.vector.AutoresetMode.NEXT_STEP)
    with pytest.raises(ValueError, match="SAME_STEP"):
        TRPO(LinearPolicy(), env)


def test_dict_observations_use_the_joints_for_the_baseline():
    torch.manual_seed(0)
    algo = TRPO(LinearPolicy(), make_env(dict_obs=True), TRPOConfig(steps_per_iter=40), seed=0)
    algo.iterate()
    algo.iterate()
    assert algo.baseline.weights.shape == (1 + 1 + 4,)  # [x, x^2, t, t^2, t^3, 1]


@pytest.mark.parametrize("fvp_subsample", [1.0, 0.25])
def test_checkpoint_resume_reproduces_the_uninterrupted_run(tmp_path, fvp_subsample):
    config = TRPOConfig(steps_per_iter=40, fvp_subsample=fvp_subsample)

    def fresh():
        torch.manual_seed(0)
        return TRPO(LinearPolicy(), lambda: make_env(), config, seed=7)

    full = fresh()
    full.run(6 * 40, csv_path=tmp_path / "full.csv", progress=False)

    first = fresh()
    first.run(2 * 40, csv_path=tmp_path / "resumed.csv", checkpoint_path=tmp_path / "ckpt.pt", progress=False)
    assert torch.load(tmp_path / "ckpt.pt", weights_only=True)["iteration"] == 2
    torch.manual_seed(123)  # a different initialisation, overwritten by the checkpoint
    second = TRPO(LinearPolicy(), lambda: make_env(), config, seed=7)
    second.load(tmp_path / "ckpt.pt")
    second.run(6 * 40, csv_path=tmp_path / "resumed.csv", progress=False)

    def without_timing(path):  # the timing columns are the last ones
        lines = path.read_text().splitlines()
        assert lines[0].split(",")[-len(TIMING_COLUMNS) :] == list(TIMING_COLUMNS)
        return [line.rsplit(",", len(TIMING_COLUMNS))[0] for line in lines]

    full_lines = without_timing(tmp_path / "full.csv")
    assert len(full_lines) == 7  # header + 6 rows
    assert without_timing(tmp_path / "resumed.csv") == full_lines
    for a, b in zip(full.policy.parameters(), second.policy.parameters()):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="different seed"):
        TRPO(LinearPolicy(), make_env(), config, seed=8).load(tmp_path / "ckpt.pt")


def test_learns_point_reach():
    torch.manual_seed(0)
    algo = TRPO(LinearPolicy(), make_env(num_envs=4), TRPOConfig(steps_per_iter=200, max_kl=0.05), seed=0)
    rows = algo.run(30 * 200, progress=False)
    first, last = np.mean([r["mean_return"] for r in rows[:3]]), np.mean([r["mean_return"] for r in rows[-3:]])
    assert last > first + 1.0
    assert sum(r["successes"] for r in rows[-3:]) > sum(r["successes"] for r in rows[:3])


def test_async_vector_env_gives_the_same_iterations_as_sync():
    rows = {}
    for asynchronous in (False, True):
        torch.manual_seed(0)
        env = make_vec_env(lambda: PointReach(), 2, asynchronous=asynchronous)
        algo = TRPO(LinearPolicy(), env, TRPOConfig(steps_per_iter=40), seed=5)
        rows[asynchronous] = [{k: v for k, v in algo.iterate().items() if k not in TIMING_COLUMNS} for _ in range(2)]
        algo.close()
    assert rows[True] == rows[False]


def test_learns_pendulum():
    """Gymnasium's Pendulum-v1 (random policy: about -1200 per episode) improves within 32k steps with the
    benchmark's policy, the package's own (:func:`pendulum_policy`; seed 0 gains about 310);
    the full 1e5-step comparison with sb3-contrib is bench_trpo_pendulum."""
    torch.manual_seed(0)
    env = make_vec_env("Pendulum-v1", 8)
    algo = TRPO(pendulum_policy(env), env, TRPOConfig(steps_per_iter=1600), seed=0)
    returns = [r["mean_return"] for r in algo.run(20 * 1600, progress=False)]
    assert np.mean(returns[-3:]) > np.mean(returns[:3]) + 200


def pieces_step(policy, params, obs, actions, advantages, config):
    """Steps 3-6 assembled from vdtutorial.trust_region, as chapter 06b's learner does, for TRPO(step=...)."""
    with torch.no_grad():
        dist = policy.distribution(obs)
        old = Normal(dist.mean.clone(), dist.stddev.clone())
        old_log_prob = old.log_prob(actions).sum(-1)

    def surrogate_and_kl():
        dist = policy.distribution(obs)
        return (torch.exp(dist.log_prob(actions).sum(-1) - old_log_prob) * advantages).mean(), mean_kl(old, dist)

    g = flat_grad(surrogate_and_kl()[0], params)
    Fvp = double_backward_fvp(policy, params, obs, old, config.cg_damping)
    s = conjugate_gradient(Fvp, g, config.cg_iters)
    full_step = math.sqrt(2 * config.max_kl / (s @ Fvp(s)).item()) * s
    fraction, improvement, kl = line_search(
        params, full_step, surrogate_and_kl, config.max_kl, config.backtrack_iters, config.backtrack_coeff
    )
    return {
        "mean_kl": kl,
        "entropy": old.entropy().sum(-1).mean().item(),
        "surrogate_improvement": improvement,
        "line_search": "rejected" if fraction is None else fraction,
    }


def test_a_step_from_the_library_pieces_reproduces_the_default_update():
    """TRPO(step=...) (chapter 06b's hook): the pieces assembled by hand give the default update's parameters and
    log."""
    runs = {}
    for step in (None, pieces_step):
        torch.manual_seed(0)
        env = make_vec_env("Pendulum-v1", 2)
        algo = TRPO(pendulum_policy(env), env, TRPOConfig(steps_per_iter=400), seed=3, step=step)
        rows = [{k: v for k, v in algo.iterate().items() if k not in TIMING_COLUMNS} for _ in range(2)]
        runs[step] = rows, [p.detach().clone() for p in algo.params], algo.baseline.weights.copy()
        algo.close()
    (rows, params, weights), (my_rows, my_params, my_weights) = runs[None], runs[pieces_step]
    assert my_rows == rows
    assert all(torch.equal(p, q) for p, q in zip(params, my_params))
    np.testing.assert_array_equal(my_weights, weights)


def test_a_step_that_returns_no_statistics_is_refused():
    env = make_env()
    algo = TRPO(LinearPolicy(), env, TRPOConfig(steps_per_iter=40), seed=0, step=lambda *args: None)
    with pytest.raises(TypeError, match="must return a dict"):
        algo.iterate()
    algo = TRPO(LinearPolicy(), env, TRPOConfig(steps_per_iter=40), seed=0, step=lambda *args: {"mean_kl": 0.0})
    with pytest.raises(TypeError, match="line_search"):
        algo.iterate()


def test_mean_kl_is_the_gaussian_kl_summed_over_actions_and_averaged_over_states():
    from vdtutorial.trust_region import mean_kl

    gen = torch.Generator().manual_seed(0)
    mu0, mu1 = torch.randn(5, 3, generator=gen), torch.randn(5, 3, generator=gen)
    s0, s1 = torch.rand(5, 3, generator=gen) + 0.1, torch.rand(5, 3, generator=gen) + 0.1
    by_hand = (torch.log(s1 / s0) + (s0**2 + (mu0 - mu1) ** 2) / (2 * s1**2) - 0.5).sum(-1).mean()
    torch.testing.assert_close(mean_kl(Normal(mu0, s0), Normal(mu1, s1)), by_hand)


def test_the_benchmark_times_the_update_from_outside_without_changing_it():
    """bench finetune's TRPO times the update's parts through the Fisher product, the baseline and the update's start
    it is given: the same iterations as a plain TRPO's, and parts that add up to the update's CPU time at most."""
    from vdtutorial.cli.bench import UPDATE_PARTS, PartTimedTRPO

    rows = {}
    for timed in (False, True):
        torch.manual_seed(0)
        env = make_vec_env("Pendulum-v1", 2)
        policy = make_policy(env.single_observation_space, 1, kind="mlp", scene_hidden=(16, 16))
        config = TRPOConfig(steps_per_iter=64)
        if timed:
            algo = PartTimedTRPO(policy, env, config, double_backward_fvp, "cpu")
        else:
            algo = TRPO(policy, env, config, seed=0)
        rows[timed] = []
        for _ in range(2):
            start = time.process_time()
            row = algo.iterate()
            cpu = time.process_time() - start
            rows[timed].append({k: v for k, v in row.items() if k not in TIMING_COLUMNS})
        env.close()
    assert rows[True] == rows[False]
    split = algo.update_split
    assert tuple(split) == UPDATE_PARTS and all(seconds >= 0 for seconds in split.values())
    assert 0 < sum(split.values()) <= cpu
