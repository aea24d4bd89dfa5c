"""The exact speed-ups of vdtutorial.fast: the fast policy gives the plain policy's distribution bit for bit, and
fast_policy wraps a policy's own networks without touching what it stores, and reuses a batch's prepared inputs only
while the batch is unchanged."""

import pytest
import torch
import torch.nn.functional as F
from test_policy import SPACES, batch, state_space

from vdtutorial import vd
from vdtutorial.fast.policy import FastGaussianPolicy, fast_policy, fused_first_layers
from vdtutorial.policy import GaussianPolicy, make_policy


@pytest.mark.parametrize("kind", list(SPACES))
def test_prepared_inputs_give_the_networks_own_outputs_bit_for_bit(kind):
    """FastGaussianPolicy.prepare() normalises once for both networks and the rgbd networks' first convolutions run as
    one: the distribution is exactly that of mu and sigma each run on the raw observations (also pruned, for a
    half-pruned first layer, and for one observation, as in a rollout step)."""
    torch.manual_seed(0)
    space = SPACES[kind]()
    policy = fast_policy(make_policy(space, action_dim=4, variational=True).eval())
    for layer in vd.svdo_layers(policy):
        with torch.no_grad():
            layer.log_sigma2.copy_(
                torch.where(torch.rand_like(layer.weight) < 0.5, 5.0, -10.0) + torch.log(layer.weight**2)
            )
    policy.prune_()
    for n in (1, 7):
        obs = batch(space, n, seed=n)
        prepared = policy.prepare(obs)
        assert prepared.sigma is prepared.mu and policy.prepare(prepared) is prepared
        assert (fused_first_layers(policy, prepared) is not None) == (kind == "rgbd")
        dist = policy.distribution(prepared)
        assert torch.equal(dist.mean, policy.mu(obs))
        assert torch.equal(dist.stddev, policy.min_std + F.softplus(policy.sigma(obs)))


def test_networks_with_different_input_bounds_do_not_share_inputs():
    policy = fast_policy(make_policy(state_space(), action_dim=2))
    with torch.no_grad():
        policy.sigma.input_scale.mul_(2)
    obs = batch(state_space(), 3)
    prepared = policy.prepare(obs)
    assert prepared.sigma is not prepared.mu
    assert torch.equal(policy.distribution(prepared).stddev, policy.min_std + F.softplus(policy.sigma(obs)))


def test_fast_policy_shares_the_networks_state_and_distribution():
    torch.manual_seed(0)
    space = SPACES["rgbd"]()
    plain = make_policy(space, action_dim=2)
    obs = batch(space, 5)
    before, keys = plain.distribution(obs), list(plain.state_dict())
    policy = fast_policy(plain)
    assert type(plain) is GaussianPolicy and type(policy) is FastGaussianPolicy and isinstance(policy, GaussianPolicy)
    assert policy.mu is plain.mu and policy.sigma is plain.sigma and policy.config == plain.config
    assert list(policy.state_dict()) == keys  # shipped run states load into either
    after = policy.distribution(obs)
    assert torch.equal(after.mean, before.mean) and torch.equal(after.stddev, before.stddev)
    assert fast_policy(policy) is policy
    with torch.no_grad():  # a step of the fast policy is a step of the plain one
        policy.mu.head[0].bias.add_(1.0)
    assert torch.equal(plain.distribution(obs).mean, policy.distribution(obs).mean)
    with pytest.raises(TypeError, match="needs a GaussianPolicy"):
        fast_policy(torch.nn.Linear(2, 2))


def test_a_batch_is_prepared_once_until_it_changes():
    torch.manual_seed(0)
    space = SPACES["rgbd"]()
    policy = fast_policy(make_policy(space, action_dim=2))
    obs = batch(space, 4)
    first = policy.prepare(obs)
    assert policy.prepare(obs) is first
    assert policy.prepare(dict(obs)) is first  # the same tensors, in another dict
    other = batch(space, 4, seed=1)
    assert policy.prepare(other) is not first
    prepared = policy.prepare(obs)
    next(iter(obs.values())).mul_(0.5)  # written in place: prepared afresh
    after = policy.prepare(obs)
    assert after is not prepared
    assert torch.equal(policy.distribution(obs).mean, policy.mu(obs))
