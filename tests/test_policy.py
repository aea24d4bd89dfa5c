"""Tests of vdtutorial.policy: the Fig. 2 network in its three kinds and the Gaussian policy."""

import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from vdtutorial import vd
from vdtutorial.analysis.compact import compact
from vdtutorial.analysis.sparsity import sparsity_report, weight_layers
from vdtutorial.policy import GaussianPolicy, PolicyNet, make_policy, obs_to_tensor

IMAGE = 48  # smallest convenient size for the default convolutions: 48 -> 11 -> 4 -> 1 pixels
JOINT_LIMIT = np.float32(2 * math.pi)


def rgbd_space(size: int = IMAGE) -> gym.spaces.Dict:
    return gym.spaces.Dict(
        {
            "rgb": gym.spaces.Box(0, 255, shape=(3, size, size), dtype=np.uint8),
            "depth": gym.spaces.Box(0.0, 3.0, shape=(size * size,), dtype=np.float32),
            "joints": gym.spaces.Box(-JOINT_LIMIT, JOINT_LIMIT, shape=(6,), dtype=np.float32),
        }
    )


def state_space() -> gym.spaces.Box:
    low = np.array([-JOINT_LIMIT] * 6 + [0.3, -0.25, 0.0], dtype=np.float32)
    high = np.array([JOINT_LIMIT] * 6 + [0.6, 0.25, 0.0], dtype=np.float32)
    return gym.spaces.Box(low, high, dtype=np.float32)


def pendulum_space() -> gym.spaces.Box:
    return gym.make("Pendulum-v1").observation_space


SPACES = {"rgbd": rgbd_space, "state": state_space, "mlp": pendulum_space}


def batch(space: gym.spaces.Space, n: int, seed: int = 0):
    """n observations drawn from ``space`` (depth entries stay in [0, 3] m), as a batched tensor or dict."""
    space.seed(seed)
    samples = [space.sample() for _ in range(n)]
    if isinstance(space, gym.spaces.Dict):
        return obs_to_tensor({key: np.stack([s[key] for s in samples]) for key in space.spaces})
    return obs_to_tensor(np.stack(samples))


@pytest.mark.parametrize("kind", list(SPACES))
@pytest.mark.parametrize("variational", [False, True])
def test_shapes_sigma_and_auto_kind(kind, variational):
    torch.manual_seed(0)
    space = SPACES[kind]()
    policy = make_policy(space, action_dim=4, variational=variational)
    assert policy.config["kind"] == kind  # "auto" picked the right streams
    assert len(policy.mu.streams) == (1 if kind == "mlp" else 2)
    obs = batch(space, 5)
    dist = policy.distribution(obs)
    assert dist.mean.shape == dist.stddev.shape == (5, 4)
    assert policy.log_prob(obs, policy.sample(obs)).shape == policy.entropy(obs).shape == (5,)
    assert (dist.stddev > 0).all()
    # Small final weights: sigma starts close to init_std = 0.3 and the mean close to 0 for any input.
    assert torch.allclose(dist.stddev, torch.full((5, 4), 0.3), atol=0.05)
    assert dist.mean.abs().max() < 0.2


def test_sigma_stays_positive_for_extreme_outputs():
    policy = make_policy(state_space(), 2, min_std=0.05)
    with torch.no_grad():
        policy.sigma.head[0].bias.fill_(-1e4)
    assert (policy.distribution(batch(state_space(), 3)).stddev >= 0.05).all()


def test_log_prob_and_entropy_match_the_gaussian_formula():
    torch.manual_seed(1)
    policy = make_policy(state_space(), 3)
    obs = batch(state_space(), 6)
    actions = torch.randn(6, 3)
    mean, std = policy.mu(obs), 0.01 + F.softplus(policy.sigma(obs))
    by_hand = (-0.5 * ((actions - mean) / std) ** 2 - torch.log(std) - 0.5 * math.log(2 * math.pi)).sum(-1)
    assert torch.allclose(policy.log_prob(obs, actions), by_hand, atol=1e-5)
    assert torch.allclose(policy.entropy(obs), (0.5 * math.log(2 * math.pi * math.e) + torch.log(std)).sum(-1))


def test_kl_is_zero_for_itself_and_positive_otherwise():
    torch.manual_seed(2)
    space = pendulum_space()
    obs = batch(space, 32)
    p, q = make_policy(space, 1), make_policy(space, 1)
    with torch.no_grad():
        q.sigma.head[0].bias.add_(0.5)
    assert p.kl(p, obs).item() == pytest.approx(0.0, abs=1e-7)
    assert p.kl(q, obs).item() > 0 and q.kl(p, obs).item() > 0
    # Against the closed form for univariate Gaussians, with the old policy given as its distribution.
    old, new = q.distribution(obs), p.distribution(obs)
    closed = torch.log(new.stddev / old.stddev) + (old.variance + (old.mean - new.mean) ** 2) / (2 * new.variance) - 0.5
    assert p.kl(old, obs).item() == pytest.approx(closed.sum(-1).mean().item(), rel=1e-5)
    p.kl(q, obs).backward()  # the old policy is a constant: only p gets gradients
    assert all(param.grad is None for param in q.parameters())


@pytest.mark.parametrize("kind", list(SPACES))
def test_variational_flag_swaps_every_layer(kind):
    plain = make_policy(SPACES[kind](), 2, variational=False)
    variational = make_policy(SPACES[kind](), 2, variational=True)
    plain_types = {type(m) for m in weight_layers(plain)}
    assert plain_types <= {nn.Linear, nn.Conv2d} and vd.svdo_layers(plain) == []
    assert {type(m) for m in weight_layers(variational)} <= {vd.LinearSVDO, vd.Conv2dSVDO}
    per_net = {"rgbd": 3 + 3 + 3 + 1, "state": 3 + 3 + 1, "mlp": 3 + 1}[kind]  # conv + FC streams + head
    assert len(weight_layers(plain)) == len(weight_layers(variational)) == 2 * per_net


@pytest.mark.parametrize("kind", list(SPACES))
def test_config_round_trip_gives_identical_outputs(kind):
    torch.manual_seed(3)
    space = SPACES[kind]()
    policy = make_policy(space, 3, variational=True, kind=kind, scene_hidden=(16, 16, 8), joint_hidden=(16, 8, 8))
    with torch.no_grad():
        for layer in vd.svdo_layers(policy):
            layer.log_sigma2.uniform_(-12, 4)
    policy.prune_()
    checkpoint = {"config": json.loads(json.dumps(policy.config)), "state_dict": policy.state_dict()}
    rebuilt = GaussianPolicy.from_config(checkpoint["config"])
    rebuilt.load_state_dict(checkpoint["state_dict"])
    assert rebuilt.config == policy.config
    obs = batch(space, 4)
    a, b = policy.distribution(obs), rebuilt.distribution(obs)
    assert torch.equal(a.mean, b.mean) and torch.equal(a.stddev, b.stddev)
    assert all(layer.pruned for layer in vd.svdo_layers(rebuilt))


@pytest.mark.parametrize("kind", ["rgbd", "state"])
def test_act_on_single_and_batched_numpy_observations(kind):
    torch.manual_seed(4)
    space = SPACES[kind]()
    policy = make_policy(space, 6)
    space.seed(0)
    single = space.sample()
    stacked = {key: np.stack([single[key]] * 3) for key in single} if kind == "rgbd" else np.stack([single] * 3)
    action = policy.act(single)
    assert isinstance(action, np.ndarray) and action.shape == (6,) and action.dtype == np.float32
    assert policy.act(stacked).shape == (3, 6)
    mean = policy.act(stacked, deterministic=True)
    assert np.allclose(mean, policy.act(single, deterministic=True), atol=1e-6)
    assert np.allclose(mean, policy.mu(obs_to_tensor(stacked)).detach().numpy())


def test_make_policy_kinds_are_explicit():
    assert make_policy(state_space(), 2, kind="mlp").config["kind"] == "mlp"  # a 9-vector as a plain MLP
    with pytest.raises(ValueError):
        make_policy(state_space(), 2, kind="rgbd")
    with pytest.raises(ValueError):
        make_policy(rgbd_space(), 2, kind="state")
    with pytest.raises(TypeError):
        make_policy(state_space(), 2, hidden=(3,))  # misspelt size


def test_inputs_are_normalised_from_the_space_bounds():
    policy = make_policy(pendulum_space(), 1)  # cos, sin in [-1, 1], angular velocity in [-8, 8]
    assert torch.equal(policy.mu.input_scale, torch.tensor([1.0, 1.0, 8.0]))
    state = make_policy(state_space(), 1)  # cup x in [0.3, 0.6], y in [-0.25, 0.25], z fixed at 0
    assert torch.allclose(state.mu.input_centre, torch.tensor([0.45, 0.0, 0.0]))
    assert torch.allclose(state.mu.input_scale, torch.tensor([0.15, 0.25, 1.0]))


def test_an_unnormalised_policy_reads_the_observation_as_it_is_and_rebuilds_so():
    policy = make_policy(pendulum_space(), 1, normalise=False)
    assert torch.equal(policy.mu.input_scale, torch.ones(3)) and torch.equal(policy.mu.input_centre, torch.zeros(3))
    obs = torch.tensor([[0.6, -0.8, 7.5]])
    assert torch.equal(policy.mu.stream_inputs(obs)[0], obs)
    rebuilt = type(policy).from_config(policy.config)
    assert torch.equal(rebuilt.mu.input_scale, torch.ones(3))


def test_compacting_a_trained_and_pruned_policy_keeps_its_outputs():
    torch.manual_seed(5)
    space = state_space()
    policy = make_policy(space, 6, variational=True)
    obs = batch(space, 256)
    target = torch.tanh(obs[:, :6] - obs[:, 6:7])  # some smooth function of the state to clone
    optimiser = torch.optim.Adam(policy.mu.parameters(), lr=1e-2)
    for step in range(150):  # behavioural-cloning-like ELBO with a strong prior, to get sparsity fast
        loss = -policy.log_prob(obs, target).mean() + min(1.0, step / 50) * vd.model_kl(policy.mu) / 256
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    policy.prune_()
    report = sparsity_report(policy.mu)
    assert report.weight_fraction > 0.5 and report.neuron_fraction > 0.1
    small = compact(policy.mu)
    assert small is not policy.mu and vd.svdo_layers(small) == []
    assert sum(p.numel() for p in small.parameters()) < sum(p.numel() for p in policy.mu.parameters()) / 2
    test_obs = batch(space, 64, seed=1)
    with torch.no_grad():
        assert torch.allclose(small(test_obs), policy.mu.eval()(test_obs), atol=1e-5)
    whole = sparsity_report(policy)  # both networks; sigma's report shows its untrained layers
    assert [layer.name.split(".")[0] for layer in whole.layers] == ["mu"] * 7 + ["sigma"] * 7


def test_compacting_an_image_network():
    torch.manual_seed(6)
    net = PolicyNet(
        "rgbd", {"rgb": (3, IMAGE, IMAGE), "depth": (IMAGE * IMAGE,), "joints": (6,)}, 6, variational=True
    ).eval()
    with torch.no_grad():
        for layer in vd.svdo_layers(net):
            layer.log_sigma2.copy_(torch.where(torch.rand_like(layer.weight) < 0.7, 10.0, -10.0))
    obs = batch(rgbd_space(), 8)
    small = compact(net)
    with torch.no_grad():
        assert torch.allclose(small(obs), net(obs), atol=1e-5)
    assert sum(p.numel() for p in small.parameters()) < sum(m.weight.numel() for m in weight_layers(net))


def test_image_inputs_are_the_documented_normalisation():
    net = make_policy(rgbd_space(), action_dim=2).mu
    obs = batch(rgbd_space(), 3)
    for depth_type in (torch.float32, torch.float16):  # pre-training stores depth as float16
        depth = obs["depth"].to(depth_type)
        image, _ = net.stream_inputs({**obs, "depth": depth})
        expected = torch.cat([obs["rgb"].to(torch.float32) / 255.0, depth.reshape(3, 1, IMAGE, IMAGE) / 3.0], dim=1)
        assert image.dtype == torch.float32 and torch.equal(image, expected - 0.5)
