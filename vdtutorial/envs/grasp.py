"""The grasping task (Section V-B): bring the open hand around a cup that can be hit.

Success is placing the hand around the cup: the hand centre within :data:`POSITION_TOLERANCE` of the grasp point on
the cup's axis and the approach axis within :data:`TILT_TOLERANCE_DEG` of horizontal. Closing the fingers is not
simulated; the paper's reward counts the placement.

The success region must be one the hand can be in: a pose that counts as a success but puts a finger into the cup or
the palm onto the table is a collision. So the cup (:data:`GRASP_CUP_RADIUS`, narrower than the reaching task's), the
grasp height (:data:`GRASP_HEIGHT`) and the tolerances are chosen together from the hand of ``jaco6.urdf``: every hand
position within the tolerance of the grasp point, at the grasp orientation, is collision-free, with a few millimetres
to spare (``tests/test_envs.py`` measures the clearances; docs/results.md, "Measurements behind the code").

Taught in chapters 01 and 08.
"""

from __future__ import annotations

import math

import numpy as np

from vdtutorial.envs.base import JacoEnv

#: Radius of the grasping task's cup (metres): it must leave room between the open fingers (see above).
GRASP_CUP_RADIUS = 0.020
#: Height of the grasp point on the cup's axis above the table (metres).
GRASP_HEIGHT = 0.095
#: Success: hand centre within this distance (metres) of the grasp point ...
POSITION_TOLERANCE = 0.02
#: ... and approach axis within this angle (degrees) of horizontal.
TILT_TOLERANCE_DEG = 10.0
#: Sparse reward: -1 every step, +25 on success, -25 on a collision (Section V-B).
STEP_COST, SUCCESS_REWARD, COLLISION_PENALTY = 1.0, 25.0, 25.0


def grasp_point(cup_position) -> np.ndarray:
    """Where the hand centre must be: on the cup's axis at :data:`GRASP_HEIGHT`."""
    return np.asarray(cup_position, dtype=np.float64) + np.array([0.0, 0.0, GRASP_HEIGHT])


def tilt_deg(approach) -> float:
    """Angle between the hand's approach axis and the horizontal plane, in degrees."""
    return math.degrees(math.asin(min(1.0, abs(float(approach[2])))))


class JacoGraspEnv(JacoEnv):
    """Grasp: reward ``-1 + 25 succ_t - 25 fail_t``; collisions with the cup, table or itself fail. ``info`` carries
    ``is_success``, ``is_failure``, ``distance`` (hand centre to grasp point) and ``tilt_deg`` (approach axis vs
    horizontal)."""

    cup_collidable = True
    cup_radius = GRASP_CUP_RADIUS
    default_image_size = 256

    def _goal_status(self):
        tcp, approach = self.scene.tcp_pose()
        d = float(np.linalg.norm(tcp - grasp_point(self.scene.cup_position)))
        tilt = tilt_deg(approach)
        return d < POSITION_TOLERANCE and tilt < TILT_TOLERANCE_DEG, {"distance": d, "tilt_deg": tilt}

    def _reward(self, action, success, failure, info):
        return -STEP_COST + SUCCESS_REWARD * success - COLLISION_PENALTY * failure
