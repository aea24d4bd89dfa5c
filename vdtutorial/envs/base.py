"""What the reaching and grasping environments share: spaces, action handling, the episode loop.

A task subclass only defines its goal (:meth:`JacoEnv._goal_status`) and its reward (:meth:`JacoEnv._reward`); the rest
-- observation modes, action checks, joint limits, collision-checked motion, the horizon, rendering -- lives here once.

Taught in chapter 01.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

from vdtutorial.envs.scene import CAMERA_FAR, CUP_RADIUS, CUP_REGION_HIGH, CUP_REGION_LOW, HOME, N_JOINTS, JacoScene

#: Episode horizon H (Section V-A): an episode is truncated after this many actions.
HORIZON = 25
#: Largest joint-angle change per action (Section V-A): each delta lies in [-pi/5, pi/5].
MAX_DELTA = math.pi / 5
OBS_MODES = ("rgbd", "state")


class JacoEnv(gym.Env):
    """A Jaco-like arm on a table with a cup; actions are joint-angle deltas.

    Parameters
    ----------
    obs_mode: ``"rgbd"`` -- the paper's observation, a dict with ``"rgb"`` (uint8, 3 x S x S, in [0, 255]),
        ``"depth"`` (float32, S * S: the S x S depth image in metres, clipped to the camera's far plane, flattened row
        by row; ``obs["depth"].reshape(S, S)`` gives the picture) and ``"joints"`` (6 angles, radians); or ``"state"``
        -- a float32 vector of the 6 joint angles followed by the cup's base position (x, y, z), the fast mode for
        classes and CI. The image layout is the one gymnasium and Stable-Baselines3 treat as an image (uint8, channels
        first), so their CNN policies read it unchanged. Depth keeps its metric precision as a flat float vector in its
        own key (no 8-bit image quantisation; Stable-Baselines3 accepts it besides a uint8 image). The paper's policy
        scales both inside the network (:mod:`vdtutorial.policy`).
    image_size: side S of the camera image in pixels.
    render_mode: ``"rgb_array"`` makes :meth:`render` return the camera's RGB image (S x S x 3, uint8).

    Actions are clipped to [-pi/5, pi/5]^6 (the paper's action range); NaN, infinity or a wrong shape raise
    ``ValueError``. The new joint angles are clipped to the joint limits, and the motion from the old to the new
    angles is checked for collisions along the way (:meth:`JacoScene.path_in_collision`).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    cup_collidable = False
    cup_radius = CUP_RADIUS
    default_image_size = 128

    def __init__(self, obs_mode: str = "rgbd", image_size: int | None = None, render_mode: str | None = None):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.obs_mode = obs_mode
        self.render_mode = render_mode
        self.scene = JacoScene(
            image_size or self.default_image_size, cup_collidable=self.cup_collidable, cup_radius=self.cup_radius
        )
        s, lo, hi = self.scene.image_size, self.scene.lower, self.scene.upper
        self.action_space = gym.spaces.Box(-MAX_DELTA, MAX_DELTA, shape=(N_JOINTS,), dtype=np.float32)
        joints = gym.spaces.Box(lo.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        if obs_mode == "rgbd":
            self.observation_space = gym.spaces.Dict(
                {
                    "rgb": gym.spaces.Box(0, 255, shape=(3, s, s), dtype=np.uint8),
                    "depth": gym.spaces.Box(0.0, CAMERA_FAR, shape=(s * s,), dtype=np.float32),
                    "joints": joints,
                }
            )
        else:
            # the cup stands on the table (z = 0); its z bounds get a small margin to keep the box non-degenerate
            low = np.concatenate([lo, CUP_REGION_LOW, [-0.01]]).astype(np.float32)
            high = np.concatenate([hi, CUP_REGION_HIGH, [0.01]]).astype(np.float32)
            self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self._t = 0

    # -- task hooks ----------------------------------------------------------------------------------
    def _goal_status(self) -> tuple[bool, dict]:
        """Whether the arm is in a goal state, plus task-specific info (e.g. the distance)."""
        raise NotImplementedError

    def _reward(self, action: np.ndarray, success: bool, failure: bool, info: dict) -> float:
        raise NotImplementedError

    # -- gymnasium API -------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Arm at the Jaco home pose; cup drawn from p0 (uniform over the table region) with the env's
        seeded generator, or placed at ``options["cup_xy"]``."""
        super().reset(seed=seed)
        if options and "cup_xy" in options:
            cup_xy = np.asarray(options["cup_xy"], dtype=np.float64)
        else:
            cup_xy = self.np_random.uniform(CUP_REGION_LOW, CUP_REGION_HIGH)
        self.set_state(HOME, cup_xy)
        self._t = 0
        _, info = self._goal_status()
        info.update(is_success=False, is_failure=False)
        return self._observation(), info

    def step(self, action):
        a = self.check_action(action)
        q_old = self.scene.joints
        q_new = np.clip(q_old + a, self.scene.lower, self.scene.upper)
        failure = self.scene.path_in_collision(q_old, q_new)
        success, info = self._goal_status()
        success = success and not failure
        self._t += 1
        info.update(is_success=success, is_failure=failure)
        reward = self._reward(a, success, failure, info)
        terminated = success or failure
        truncated = (not terminated) and self._t >= HORIZON
        return self._observation(), float(reward), terminated, truncated, info

    def render(self):
        if self.render_mode == "rgb_array":
            return self.scene.render_rgbd()[0]
        return None

    def close(self):
        self.scene.close()

    # -- helpers -------------------------------------------------------------------------------------
    def check_action(self, action) -> np.ndarray:
        """The action as float64 of shape (6,), clipped to [-pi/5, pi/5]; ValueError if malformed."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"action must be 6 numbers (joint-angle deltas in radians), got {action!r}") from exc
        if a.shape != (N_JOINTS,):
            raise ValueError(f"action must have shape ({N_JOINTS},) (one delta per joint), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite, got {a.tolist()}")
        return np.clip(a, -MAX_DELTA, MAX_DELTA)

    def set_state(self, joints, cup_xy) -> None:
        """Put the scene in a given state (used by reset, and to re-render stored demonstrations)."""
        self.scene.set_cup(cup_xy)
        self.scene.set_joints(joints)

    @property
    def joints(self) -> np.ndarray:
        return self.scene.joints.copy()

    @property
    def cup_position(self) -> np.ndarray:
        return self.scene.cup_position.copy()

    def _observation(self):
        joints = self.scene.joints.astype(np.float32)
        if self.obs_mode == "state":
            return np.concatenate([joints, self.scene.cup_position.astype(np.float32)])
        rgb, depth = self.scene.render_rgbd()
        return {
            "rgb": np.ascontiguousarray(rgb.transpose(2, 0, 1)),
            "depth": np.minimum(depth, CAMERA_FAR).reshape(-1),
            "joints": joints,
        }

    def observation_at(self, joints, cup_xy):
        """The observation the env would give in a state (joints, cup): re-renders deterministically."""
        self.set_state(joints, cup_xy)
        return self._observation()
