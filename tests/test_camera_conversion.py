"""The camera image is the same whether pybullet hands it over as numpy arrays or as flat Python tuples.

pybullet built with numpy support returns ``getCameraImage``'s buffers as numpy arrays; a build without it
(a source build in pip's isolated environment) returns flat tuples of ints and floats. The tuple form is
simulated here from a real image, so the check runs with either build.
"""

import gymnasium as gym
import numpy as np
import pybullet
import pytest

from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.scene import camera_buffers


def as_numpy_build(rgba, zbuf, size):
    """What pybullet with numpy support returns: uint8 (S, S, 4) and float32 (S, S) arrays."""
    return (
        np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4),
        np.asarray(zbuf, dtype=np.float32).reshape(size, size),
    )


def as_plain_build(rgba, zbuf, sequence=tuple):
    """What pybullet without numpy support returns: flat sequences of Python ints and floats."""
    return (sequence(int(v) for v in np.ravel(rgba)), sequence(float(v) for v in np.ravel(zbuf)))


def assert_identical(a, b):
    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def raw_image(scene):
    s = scene.image_size
    _, _, rgba, zbuf, _ = pybullet.getCameraImage(
        s,
        s,
        scene._view,
        scene._proj,
        shadow=0,
        renderer=pybullet.ER_TINY_RENDERER,
        flags=pybullet.ER_NO_SEGMENTATION_MASK,
        physicsClientId=scene.client,
    )
    return rgba, zbuf


@pytest.mark.parametrize("sequence", [tuple, list])
@pytest.mark.parametrize("size", [16, 37])
def test_sequences_convert_to_the_same_arrays_as_numpy_buffers(size, sequence):
    env = gym.make(ENV_IDS["reach"], obs_mode="rgbd", image_size=size)
    try:
        env.reset(seed=3)
        rgba, zbuf = as_numpy_build(*raw_image(env.unwrapped.scene), size)
    finally:
        env.close()
    assert 0.0 < zbuf.min() < zbuf.max() < 1.0 and rgba[..., :3].min() < rgba[..., :3].max()  # a real picture
    from_sequences = camera_buffers(*as_plain_build(rgba, zbuf, sequence))
    for a, b in zip(from_sequences, (rgba, zbuf)):
        assert_identical(a, b.reshape(-1))
    assert from_sequences[0].flags.writeable  # the RGB image leaves render_rgbd as a view of it


def test_render_rgbd_is_the_same_when_pybullet_returns_tuples(monkeypatch):
    env = gym.make(ENV_IDS["reach"], obs_mode="rgbd", image_size=32, render_mode="rgb_array")
    try:
        env.reset(seed=5)
        scene = env.unwrapped.scene
        rng = np.random.default_rng(0)
        states = [env.step(rng.uniform(-0.6, 0.6, 6))[0] for _ in range(3)]
        real = [scene.render_rgbd(), env.render()]
        real_getCameraImage, calls = pybullet.getCameraImage, []

        def plain_build(*args, **kwargs):
            w, h, rgba, zbuf, seg = real_getCameraImage(*args, **kwargs)
            calls.append(1)
            return (w, h, *as_plain_build(rgba, zbuf), tuple(int(v) for v in np.ravel(seg)))

        monkeypatch.setattr(pybullet, "getCameraImage", plain_build)
        plain = [scene.render_rgbd(), env.render()]
        env.reset(seed=5)
        rng = np.random.default_rng(0)
        plain_states = [env.step(rng.uniform(-0.6, 0.6, 6))[0] for _ in range(3)]
    finally:
        monkeypatch.undo()
        env.close()
    assert len(calls) == 2 + 1 + 3  # the tuples were used: two renders, reset, three steps
    (rgb, depth), frame = real
    (plain_rgb, plain_depth), plain_frame = plain
    for a, b in ((rgb, plain_rgb), (depth, plain_depth), (frame, plain_frame)):
        assert_identical(a, b)
        assert b.flags.writeable
    for obs, plain_obs in zip(states, plain_states):
        assert obs.keys() == plain_obs.keys()
        for key in obs:
            assert_identical(obs[key], plain_obs[key])
