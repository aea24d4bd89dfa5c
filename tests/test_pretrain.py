"""Behavioural cloning: what VD and L2 pre-training train, freeze, report and save."""
import gymnasium as gym
import numpy as np
import pytest
import torch

from vdtutorial.demos import generate_demos
from vdtutorial.envs import ENV_IDS
from vdtutorial.evaluation import PolicyController, successes_per_episode
from vdtutorial.pretrain import (CheckpointError, PretrainConfig, checkpoint_path, demo_observations,
                                 load_checkpoint, pretrain, save_checkpoint, split_by_episode)
from vdtutorial.vd import LinearSVDO, sparsity_report


@pytest.fixture(scope="module")
def demos():
    return generate_demos("reach", 600, 0.3, seed=2, progress=False)


@pytest.fixture(scope="module")
def trained(demos):
    torch.set_num_threads(1)
    out = {}
    for reg in ("vd", "l2"):
        out[reg] = pretrain(demos, PretrainConfig(reg=reg, epochs=20), seed=0, progress=False)
    return out


def test_imitation_error_falls_and_sigma_is_frozen(demos, trained):
    from vdtutorial.policy import make_policy
    from vdtutorial.pretrain import observation_space

    guess_zero = float((demos.actions ** 2).mean())  # held-out error of always predicting no motion
    for reg, (policy, history) in trained.items():
        assert history[-1]["val_mse"] < history[0]["val_mse"] and history[-1]["val_mse"] < 0.9 * guess_zero, reg
        torch.manual_seed(0)
        fresh = make_policy(observation_space("reach", "state"), 6, variational=reg == "vd")
        for (name, p), (_, q) in zip(policy.sigma.named_parameters(), fresh.sigma.named_parameters()):
            torch.testing.assert_close(p, q, msg=f"{reg}: sigma.{name} changed in pre-training")


def test_vd_prunes_and_l2_does_not(trained):
    vd, _ = trained["vd"]
    l2, _ = trained["l2"]
    assert any(isinstance(m, LinearSVDO) for m in vd.mu.modules())
    assert not any(isinstance(m, LinearSVDO) for m in l2.mu.modules())
    report = sparsity_report(vd.mu)
    assert report.weight_fraction > 0.3
    assert trained["vd"][1][-1]["weights_pruned"] == pytest.approx(report.weight_fraction)


def test_same_seed_same_policy(demos, trained):
    again, _ = pretrain(demos, PretrainConfig(reg="vd", epochs=20), seed=0, progress=False)
    for p, q in zip(again.parameters(), trained["vd"][0].parameters()):
        torch.testing.assert_close(p, q)


def test_held_out_split_is_by_whole_episodes(demos):
    train, val = split_by_episode(demos, 0.2, seed=0)
    assert len(np.intersect1d(demos.episode[train], demos.episode[val])) == 0
    assert len(train) + len(val) == len(demos) and len(val) > 0


def test_pretrained_policy_acts_in_the_environment(trained):
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    out = successes_per_episode(env, PolicyController(trained["l2"][0]), steps=50, seed=0)
    assert out["trajectories"] >= 2  # trajectories end (success, failure or horizon) and restart
    env.close()


def test_checkpoint_round_trip_and_errors(demos, trained, tmp_path):
    policy, _ = trained["vd"]
    path = save_checkpoint(policy, checkpoint_path(demos.meta, "vd", "state", 0, root=tmp_path))
    assert path.name == "reach_n600_sigma0.3_vd_state_seed0.pt"
    loaded = load_checkpoint(path, kind="state", variational=True, task="reach")
    obs = torch.as_tensor(demos.states[:20])
    torch.testing.assert_close(loaded.distribution(obs).mean, policy.distribution(obs).mean)
    with pytest.raises(CheckpointError, match="variational=True, expected False"):
        load_checkpoint(path, variational=False)
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="bad.pt.*corrupt"):
        load_checkpoint(bad)


def test_rgbd_pretraining_runs_on_rerendered_images(demos):
    small = generate_demos("reach", 40, 0.3, seed=3, progress=False)
    obs = demo_observations(small, "rgbd", image_size=64)
    assert obs["rgb"].shape == (40, 3, 64, 64) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (40, 64 * 64)
    policy, history = pretrain(small, PretrainConfig(reg="vd", obs_mode="rgbd", image_size=64, epochs=1, batch_size=20, val_fraction=0.3),
                               seed=0, progress=False, observations=obs)
    assert np.isfinite(history[-1]["val_mse"])


def test_bad_configuration():
    with pytest.raises(ValueError, match="reg"):
        PretrainConfig(reg="dropout")
    with pytest.raises(ValueError, match="obs_mode"):
        PretrainConfig(obs_mode="pixels")
