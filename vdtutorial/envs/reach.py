"""The reaching task (Section V-A): put the gripper over a cup that cannot be hit. Taught in chapter 01."""

from __future__ import annotations

import numpy as np

from vdtutorial.envs.base import JacoEnv
from vdtutorial.envs.scene import CUP_HEIGHT

#: The goal point is this far above the cup's rim: "the gripper over the cup".
HOVER_HEIGHT = 0.10
#: Success when the hand centre is within this distance (metres) of the goal point.
SUCCESS_TOLERANCE = 0.05
#: Eq. 11 coefficients: c1 rewards success, c2 punishes failure (the paper's 20 and 50).
C_SUCCESS, C_FAILURE = 20.0, 50.0


def reach_goal(cup_position) -> np.ndarray:
    """The point the hand centre must reach: above the centre of the cup's rim."""
    return np.asarray(cup_position, dtype=np.float64) + np.array([0.0, 0.0, CUP_HEIGHT + HOVER_HEIGHT])


class JacoReachEnv(JacoEnv):
    """Reach: reward eq. 11, ``R_t = -|a_{t-1}|_2 - d_t + 20 succ_t - 50 fail_t``, ``d_t`` the distance of the hand
    centre from the goal point :func:`reach_goal`. Success (within :data:`SUCCESS_TOLERANCE`) and failure (collision
    with the table or itself) end the episode. ``info`` carries ``is_success``, ``is_failure`` and ``distance``."""

    cup_collidable = False
    default_image_size = 128

    def _goal_status(self):
        tcp, _ = self.scene.tcp_pose()
        d = float(np.linalg.norm(tcp - reach_goal(self.scene.cup_position)))
        return d < SUCCESS_TOLERANCE, {"distance": d}

    def _reward(self, action, success, failure, info):
        return -float(np.linalg.norm(action)) - info["distance"] + C_SUCCESS * success - C_FAILURE * failure
