"""DART's noise estimate and DAgger's aggregation (vdtutorial.beyond.dart, vdtutorial.beyond.dagger,
vdtutorial.beyond.imitation_rounds)."""

import numpy as np
import pytest

from vdtutorial.beyond.dagger import dagger, mixture
from vdtutorial.beyond.dart import noise_estimate, noisy_expert, sigma_per_joint
from vdtutorial.beyond.imitation_rounds import round_sizes
from vdtutorial.pretrain import PretrainConfig

from conftest import assert_expert_labels


def test_dart_estimate_recovers_the_error_covariance_of_a_linear_learner():
    """Expert pi*(x) = A x, learner pi(x) = (A + B) x, x ~ N(0, I): the error B x has covariance B B^T."""
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(6, 9)), 0.1 * rng.normal(size=(6, 9))
    x = rng.normal(size=(200_000, 9))
    errors = x @ (A + B).T - x @ A.T
    estimate = noise_estimate(errors)
    np.testing.assert_allclose(estimate, B @ B.T, atol=0.02 * np.abs(B @ B.T).max())
    assert np.allclose(estimate, estimate.T)
    # a learner that is always off the same way: DART's estimate keeps that offset (it is not centred)
    np.testing.assert_allclose(noise_estimate(np.tile([0.3, -0.1], (50, 1))), [[0.09, -0.03], [-0.03, 0.01]])


def test_dart_scaled_variant_sets_the_total_error_to_alpha():
    errors = np.random.default_rng(1).normal(size=(1000, 6)) * [0.1, 0.2, 0.3, 0.1, 0.1, 0.1]
    scaled = noise_estimate(errors, alpha=2.0, horizon=25)
    assert np.trace(scaled) == pytest.approx(2.0 / 25)
    np.testing.assert_allclose(scaled / np.trace(scaled), noise_estimate(errors) / np.trace(noise_estimate(errors)))
    with pytest.raises(ValueError):
        noise_estimate(errors, alpha=2.0)
    with pytest.raises(ValueError):
        noise_estimate(np.empty((0, 6)))


def test_noisy_expert_draws_the_estimated_covariance():
    covariance = np.array([[0.04, 0.01], [0.01, 0.09]])
    behaviour, rng = noisy_expert(covariance), np.random.default_rng(2)
    a_exp = np.array([0.5, -0.2])
    draws = np.array([behaviour(None, a_exp, rng) for _ in range(40_000)])
    np.testing.assert_allclose(draws.mean(axis=0), a_exp, atol=0.005)
    np.testing.assert_allclose(np.cov(draws.T), covariance, atol=0.003)
    np.testing.assert_allclose(sigma_per_joint(covariance), [0.2, 0.3])


def test_round_sizes_split_the_labels_exactly():
    assert round_sizes(8000, 4) == [2000] * 4
    assert round_sizes(10, 3) == [4, 3, 3]
    with pytest.raises(ValueError):
        round_sizes(2, 3)


def test_mixture_is_the_expert_in_round_zero_and_the_learner_when_beta_is_zero():
    class Learner:
        def eval(self):
            return self

        def act(self, state, deterministic):
            return np.full(6, 7.0)

    rng, a_exp = np.random.default_rng(0), np.zeros(6)
    assert mixture(None, 1.0)(None, a_exp, rng) is a_exp
    assert np.all(mixture(Learner(), 0.0)(np.zeros(9), a_exp, rng) == 7.0)
    chosen = [mixture(Learner(), 0.5)(np.zeros(9), a_exp, rng)[0] for _ in range(2000)]
    assert np.mean(np.equal(chosen, 0.0)) == pytest.approx(0.5, abs=0.05)


@pytest.fixture(scope="module")
def dagger_run():
    return dagger("reach", "l2", samples=60, rounds=3, seed=4, config=PretrainConfig(reg="l2", epochs=3))


def test_dagger_aggregates_exactly_the_visited_states(dagger_run):
    result = dagger_run
    assert [len(part) for part in result.parts] == [20, 20, 20]
    assert [r["labels_total"] for r in result.rounds] == [20, 40, 60]
    assert [r["expert_queries"] for r in result.rounds] == [20, 20, 20] and result.expert_queries == 60
    assert [r["beta"] for r in result.rounds] == [1.0, 0.5, 0.25]
    assert result.expert_seconds > 0
    for name in ("joints", "cup", "actions", "t"):
        np.testing.assert_array_equal(
            getattr(result.demos, name), np.concatenate([getattr(p, name) for p in result.parts])
        )
    # episodes of different rounds stay distinct, so the held-out split keeps whole episodes
    starts = np.cumsum([0] + [len(p) for p in result.parts])
    for k in range(2):
        assert result.demos.episode[starts[k + 1] - 1] < result.demos.episode[starts[k + 1]]


def test_dagger_labels_are_the_experts_actions_in_the_learners_states(dagger_run):
    demos = dagger_run.demos
    later = np.arange(len(dagger_run.parts[0]), len(demos))  # states visited with the learner acting
    assert_expert_labels(demos, np.unique(demos.episode[later])[:3])
