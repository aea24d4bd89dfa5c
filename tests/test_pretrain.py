"""Behavioural cloning: what VD and L2 pre-training train, freeze, report and save."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from vdtutorial.analysis.sparsity import sparsity_report
from vdtutorial.demos import generate_demos
from vdtutorial.envs import ENV_IDS
from vdtutorial.experiments.checkpoints import CheckpointError, checkpoint_path, load_checkpoint, save_checkpoint
from vdtutorial.experiments.evaluation import PolicyController, successes_per_episode
from vdtutorial.pretrain import (
    HeldOutStop,
    PretrainConfig,
    demo_observations,
    evaluate_imitation,
    pretrain,
    split_by_episode,
)
from vdtutorial.vd import LinearSVDO


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

    guess_zero = float((demos.actions**2).mean())  # held-out error of always predicting no motion
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


def test_without_a_configuration_pretrain_uses_the_one_its_docstring_names():
    doc = " ".join(pretrain.__doc__.split())
    assert "(default: ``PretrainConfig()``, the paper's setting" in doc and "default: :func:`default_config`" not in doc
    small = generate_demos("reach", 120, 0.3, seed=4, progress=False)
    (plain, _), (named, _) = (
        pretrain(small, seed=0, progress=False),
        pretrain(small, PretrainConfig(), seed=0, progress=False),
    )
    for p, q in zip(plain.state_dict().values(), named.state_dict().values()):
        assert torch.equal(p, q)


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
    assert path.name == "reach_n600_sigma0.3_demos2_vd_state_seed0.pt"  # the fixture's demonstrations are seed 2's
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
    policy, history = pretrain(
        small,
        PretrainConfig(reg="vd", obs_mode="rgbd", image_size=64, epochs=1, batch_size=20, val_fraction=0.3),
        seed=0,
        progress=False,
        observations=obs,
    )
    assert np.isfinite(history[-1]["val_mse"])


def test_bad_configuration():
    with pytest.raises(ValueError, match="reg"):
        PretrainConfig(reg="dropout")
    with pytest.raises(ValueError, match="obs_mode"):
        PretrainConfig(obs_mode="pixels")


def test_the_held_out_stop_waits_for_the_warm_up_and_keeps_the_best_epoch():
    net = torch.nn.Linear(1, 1)
    stop = HeldOutStop(patience=2, after=3)
    losses = [0.1, 0.05, 0.5, 0.4, 0.3, 0.35, 0.32, 0.2]  # epochs 1-2 fall inside the warm-up: not counted
    stopped = None
    for epoch, mse in enumerate(losses, start=1):
        with torch.no_grad():
            net.weight.fill_(epoch)
        if stop.should_stop(epoch, mse, net):
            stopped = epoch
            break
    assert (stopped, stop.best_epoch, stop.best_mse) == (7, 5, 0.3)
    stop.restore(net)
    assert net.weight.item() == 5.0


def test_cloning_with_patience_stops_on_the_held_out_mse_and_returns_the_best_mu(demos):
    torch.set_num_threads(1)
    config = PretrainConfig(reg="l2", epochs=80, patience=3)
    policy, history = pretrain(demos, config, seed=0, progress=False)
    mses = [row["val_mse"] for row in history]
    best = int(np.argmin(mses)) + 1
    assert policy.pretrain_info["best_epoch"] == best and policy.pretrain_info["epochs_run"] == len(history)
    assert len(history) == min(best + 3, 80) and len(history) < 80  # it stopped before the cap
    obs = demo_observations(demos, "state")
    _, val_idx = split_by_episode(demos, config.val_fraction, 0)
    again = evaluate_imitation(policy, obs, torch.as_tensor(demos.actions, dtype=torch.float32), val_idx)
    assert again["val_mse"] == pytest.approx(mses[best - 1], rel=1e-6)
    assert checkpoint_path(demos.meta, "l2", "state", 0, patience=3).name.endswith("_seed0_stop3.pt")


def test_patience_needs_a_held_out_split():
    with pytest.raises(ValueError, match="patience"):
        PretrainConfig(patience=5, val_fraction=0.0)
    with pytest.raises(ValueError, match="patience"):
        PretrainConfig(patience=0)


def test_a_checkpoint_is_named_after_its_data_set_and_both_names_read_back():
    from vdtutorial import demos as demos_module
    from vdtutorial.demos import data_set_name, demo_path
    from vdtutorial.experiments import checkpoints as checkpoints_module

    meta = {"task": "reach", "samples": 4000, "noise": 0.25}
    data_file, checkpoint = demo_path("reach", 4000, 0.25, 3), checkpoint_path(meta, "vd", "rgbd", 2)
    assert data_file.name.startswith(data_set_name("reach", 4000, 0.25) + "_seed")
    assert checkpoint.name.startswith(data_file.name.split("_seed")[0] + "_vd_rgbd")
    read = demos_module._NAME.fullmatch(data_file.name), checkpoints_module._NAME.fullmatch(checkpoint.name)
    assert [(m["task"], int(m["samples"]), float(m["noise"])) for m in read] == [("reach", 4000, 0.25)] * 2
    assert (read[0]["seed"], read[1]["seed"], read[1]["reg"], read[1]["obs"]) == ("3", "2", "vd", "rgbd")


def test_cloning_keeps_sigma_fixed_but_draws_its_weight_noise_as_the_docstring_says():
    """Pre-training puts the whole VD policy in training mode: the sigma network's layers then sample weight
    noise while their parameters stay fixed. The shipped checkpoints were made so, and the module docstring
    says so (it used to describe sigma as deterministic)."""
    import vdtutorial.pretrain as pretrain_module
    from vdtutorial.vd import svdo_layers

    small = generate_demos("reach", 120, 0.5, seed=5, progress=False)
    modes, made = [], []
    original = pretrain_module.make_policy

    def recording_policy(*args, **kwargs):
        policy = original(*args, **kwargs)
        made.append({k: v.clone() for k, v in policy.sigma.state_dict().items()})
        svdo_layers(policy.sigma)[0].register_forward_hook(lambda layer, inputs, output: modes.append(layer.training))
        return policy

    pretrain_module.make_policy = recording_policy
    try:
        policy, _ = pretrain(small, PretrainConfig(reg="vd", epochs=1, batch_size=40), seed=0, progress=False)
    finally:
        pretrain_module.make_policy = original
    assert True in modes, "sigma's VD layers were never in training mode during cloning"
    assert all(
        torch.equal(value, made[0][key])
        for key, value in policy.sigma.state_dict().items()
        if not key.endswith("bias") or "head" not in key
    )
    assert "draw weight noise" in pretrain_module.__doc__


def test_the_images_pretraining_renders_are_the_data_sets_own_in_float16_depth():
    """One re-renderer (Demos.observations): pre-training keeps the RGB and stores depth as float16."""
    small = generate_demos("reach", 30, 0.5, seed=6, progress=False)
    env = gym.make(ENV_IDS["reach"], obs_mode="rgbd", image_size=32)
    try:
        full = small.observations(env, [0, 7, 19])
    finally:
        env.close()
    obs = demo_observations(small, "rgbd", image_size=32, indices=[0, 7, 19])
    assert obs["depth"].dtype == np.float16 and full["depth"].dtype == np.float32
    assert np.array_equal(obs["rgb"], full["rgb"]) and np.array_equal(obs["depth"], full["depth"].astype(np.float16))
    assert np.array_equal(obs["joints"], small.joints[[0, 7, 19]].astype(np.float32))
