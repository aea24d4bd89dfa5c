"""The image observation as standard RL libraries expect it (uint8 RGB channels first, metric depth in
its own key), the memory it saves, and the shipped image checkpoints reading it unchanged."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

from vdtutorial.envs import ENV_IDS
from vdtutorial.experiments.checkpoints import load_checkpoint
from vdtutorial.policy import obs_to_tensor
from vdtutorial.settings import data_dir


def test_image_observation_is_uint8_rgb_plus_float_depth_and_2_3x_smaller():
    env = gym.make(ENV_IDS["reach"], obs_mode="rgbd")  # the paper's 128 x 128
    obs, _ = env.reset(seed=0)
    env.close()
    assert obs["rgb"].dtype == np.uint8 and obs["rgb"].shape == (3, 128, 128)
    assert obs["depth"].dtype == np.float32 and obs["depth"].shape == (128 * 128,)
    new = sum(v.nbytes for v in obs.values())
    legacy = 4 * 128 * 128 * 4 + obs["joints"].nbytes  # the former float32 4 x S x S "rgbd" array
    assert new == 3 * 128 * 128 + 4 * 128 * 128 + 24
    assert legacy / new == pytest.approx(2.29, abs=0.01)  # RGB is 4x smaller; depth stays float32


def test_shipped_image_checkpoint_sees_the_same_input_as_before():
    """Checkpoints made when the env gave one float32 RGBD array keep their meaning: the network's
    4-channel input built from the new (rgb, depth) pair equals the old array, bit for bit."""
    policy = load_checkpoint(data_dir() / "checkpoints" / "reach_n8000_sigma0.5_vd_rgbd_seed0.pt")
    env = gym.make(ENV_IDS["reach"], obs_mode="rgbd")
    obs, _ = env.reset(seed=3)
    rgb, depth = env.unwrapped.scene.render_rgbd()
    env.close()
    legacy = np.empty((1, 4, 128, 128), dtype=np.float32)
    legacy[0, :3] = rgb.transpose(2, 0, 1) / np.float32(255.0)
    legacy[0, 3] = np.minimum(depth, 3.0) / np.float32(3.0)
    batch = obs_to_tensor({k: v[None] for k, v in obs.items()})
    image, _ = policy.mu.stream_inputs(batch)
    assert torch.equal(image, torch.from_numpy(legacy) - 0.5)
    assert np.isfinite(policy.act(obs, deterministic=True)).all()


def test_sb3_contrib_trpo_uses_its_cnn_on_the_rgbd_observation():
    """sb3's check_env raises no warning, its default MultiInputPolicy puts its CNN on "rgb" (not an
    MLP on flattened floats), and TRPO trains 1024 steps. sb3 recommends actions in [-1, 1]; ours are
    the paper's joint deltas in [-pi/5, pi/5], so the env is wrapped in gymnasium's RescaleAction."""
    pytest.importorskip("sb3_contrib")
    from sb3_contrib import TRPO
    from stable_baselines3.common.env_checker import check_env
    from stable_baselines3.common.torch_layers import NatureCNN

    torch.set_num_threads(1)
    one = np.float32(1.0)
    env = gym.wrappers.RescaleAction(gym.make(ENV_IDS["reach"], obs_mode="rgbd", image_size=36), -one, one)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning from the checker fails the test
        check_env(env)
    model = TRPO("MultiInputPolicy", env, n_steps=1024, batch_size=128, seed=0)
    extractors = model.policy.features_extractor.extractors
    assert isinstance(extractors["rgb"], NatureCNN)
    assert not isinstance(extractors["depth"], NatureCNN) and not isinstance(extractors["joints"], NatureCNN)
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(1024)
    assert model.num_timesteps == 1024
    assert any(not torch.equal(a, b) for a, b in zip(before, model.policy.parameters()))
    env.close()
