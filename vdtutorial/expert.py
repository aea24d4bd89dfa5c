"""Section V's inverse-kinematics expert: the set G of goal configurations (eq. 9) and the expert's action (eq. 10).

For each cup position we solve inverse kinematics from several start poses and hand orientations, keep the solutions
that are within the joint limits, collision-free and put the hand where the task wants it, and drop near-duplicates:
that is G. The expert heads for the member of G nearest in L1 (eq. 9) along a straight joint-space line, moving the
joint that has furthest to go by pi/5 (eq. 10).

Why pybullet's IK and not our own: ``calculateInverseKinematics`` is a fast damped-least-squares solver in C++;
called from several rest poses with null-space limits it returns distinct arm postures (elbow and wrist variants) for
the same hand pose. We refine each answer by re-solving from it a few times and then *verify* it with forward
kinematics, so the solver's approximations never reach G.

Two changes to eq. 10 taken literally, both needed to reach the goal:

* Overshoot. Eq. 10 always moves the furthest joint by exactly pi/5, so once the arm is closer than pi/5 to g* it
  jumps past it and oscillates. We take ``min(1, (pi/5) / max_i |g*_i - j_i|)`` of the difference instead: the
  paper's step far away, the exact remaining difference near the goal.
* Wrap-around. Joints 1, 4 and 6 of the Jaco turn without end (we bound them to +-2 pi). A goal angle g_i and
  g_i +- 2 pi are the same posture, so eq. 9's L1 distance is taken to the nearest equivalent angle within the
  limits, and eq. 10 moves towards that one.

Taught in chapter 02.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as p

from vdtutorial.envs.base import MAX_DELTA, JacoEnv
from vdtutorial.envs.grasp import JacoGraspEnv, grasp_point
from vdtutorial.envs.reach import reach_goal
from vdtutorial.envs.scene import HOME, LINKS, N_JOINTS, JacoScene

#: Joints that turn without end (joint 1, 4, 6 of the Jaco): 2 pi-equivalent angles are one posture.
CONTINUOUS = np.array([True, False, False, True, False, True])
#: Stand-off d_g of the grasp expert: the pre-grasp pose puts the hand this far from the cup's axis.
GRASP_STANDOFF = 0.13
#: The grasp expert's final approach starts where the hand is within this distance of the grasp point
#: (d_g plus a margin for a pre-grasp pose reached approximately) ...
FINAL_APPROACH_DISTANCE = GRASP_STANDOFF + 0.02
#: ... and its approach axis points at the grasp point within this angle (degrees).
FINAL_APPROACH_ANGLE_DEG = 15.0
#: IK answers closer than this (max abs joint difference, radians) to one already in G are duplicates.
DISTINCT = 0.35
#: A verified IK answer puts the hand within this distance (metres) of its target ...
IK_POSITION_TOL = 0.01
#: ... and its approach axis within this angle (degrees) of the wanted direction.
IK_ANGLE_TOL_DEG = 8.0


def _rest_poses() -> list[np.ndarray]:
    """Start poses for IK: home, and home with the shoulder/elbow/wrist moved, to find distinct postures."""
    poses = [HOME.copy()]
    for d2, d3, d5 in ((0.4, -0.6, 0.0), (0.0, 0.0, 1.2)):
        q = HOME.copy()
        q[1] += d2
        q[2] += d3
        q[4] += d5
        poses.append(q)
    return poses


REST_POSES = _rest_poses()


def orientation_from_axes(approach, up) -> tuple:
    """Quaternion of a hand frame whose z axis is ``approach`` and whose y axis is as close to ``up``
    as possible (the URDF's hand frame: fingers along +z, one finger towards +y)."""
    z = np.asarray(approach, float) / np.linalg.norm(approach)
    y = np.asarray(up, float) - np.dot(up, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    m = np.column_stack([x, y, z])
    # rotation matrix -> quaternion (x, y, z, w)
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    if w > 1e-6:
        return ((m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w), w)
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    r = math.sqrt(max(0.0, 1 + m[i, i] - m[j, j] - m[k, k]))
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = r / 2
    q[j] = (m[j, i] + m[i, j]) / (2 * r)
    q[k] = (m[k, i] + m[i, k]) / (2 * r)
    q[3] = (m[k, j] - m[j, k]) / (2 * r)
    return tuple(q)


def solve_ik(scene: JacoScene, position, orientation, seed_q, refinements: int = 3) -> np.ndarray | None:
    """One IK answer from start pose ``seed_q``, refined by re-solving from itself; None if it fails
    verification (limits, hand pose, collisions). Leaves the scene's joints where they were."""
    c, arm = scene.client, scene.arm
    saved = scene.joints.copy()
    lo, hi = scene.lower, scene.upper
    q = np.asarray(seed_q, float)
    try:
        for _ in range(refinements):
            scene.set_joints(q)
            q = np.array(
                p.calculateInverseKinematics(
                    arm,
                    LINKS["tcp"],
                    position,
                    orientation,
                    lowerLimits=lo.tolist(),
                    upperLimits=hi.tolist(),
                    jointRanges=(hi - lo).tolist(),
                    restPoses=list(seed_q),
                    maxNumIterations=100,
                    residualThreshold=1e-5,
                    physicsClientId=c,
                )[:N_JOINTS]
            )
        if np.any(q < lo - 1e-6) or np.any(q > hi + 1e-6):
            return None
        scene.set_joints(q)
        tcp, approach = scene.tcp_pose()
        want = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)[:, 2]
        angle = math.degrees(math.acos(float(np.clip(np.dot(approach, want), -1, 1))))
        if np.linalg.norm(tcp - np.asarray(position)) > IK_POSITION_TOL or angle > IK_ANGLE_TOL_DEG:
            return None
        if scene.in_collision():
            return None
        return q
    finally:
        scene.set_joints(saved)


def solution_set(scene: JacoScene, targets) -> np.ndarray:
    """The set G: distinct verified IK answers over (position, orientation) targets x rest poses."""
    found: list[np.ndarray] = []
    for position, orientation in targets:
        for rest in REST_POSES:
            q = solve_ik(scene, position, orientation, rest)
            if q is not None and all(np.max(np.abs(q - g)) > DISTINCT for g in found):
                found.append(q)
    return np.array(found).reshape(-1, N_JOINTS)


def reach_targets(cup_position, n_roll: int = 4, tilts_deg=(-35.0, 0.0, 60.0)):
    """Hand poses over the cup: hand centre at the reach goal, approach axis pointing down, tilted towards the base
    (near the base the wrist's joint 5 cannot bend far enough to point straight down) or away from it (a folded elbow).

    Wrist-roll variants in G (reaching): each pose is also turned about its approach axis in ``n_roll`` steps (default
    4 of 90 degrees). The hand centre lies on joint 6's axis, so the roll cannot change success; it gives eq. 9 more
    goals and a faster expert, and the paper asks for "several distinct valid joint configurations". What the
    variants change: docs/results.md, "Measurements behind the code"."""
    goal = reach_goal(cup_position)
    out = np.array([goal[0], goal[1], 0.0]) / np.hypot(goal[0], goal[1])
    for tilt in np.radians(tilts_deg):
        approach = math.cos(tilt) * np.array([0.0, 0.0, -1.0]) + math.sin(tilt) * out
        for k in range(n_roll):
            roll = 2 * math.pi * k / n_roll
            up = math.cos(roll) * out + math.sin(roll) * np.cross(approach, out)
            yield goal, orientation_from_axes(approach, up)


def grasp_targets(cup_position, standoff: float = GRASP_STANDOFF, azimuths_deg=(-40, -20, 0, 20, 40)):
    """Pre-grasp hand poses: d_g from the cup's axis at grasp height, approach axis horizontal and
    pointing at the cup, one finger up; approached from directions around the line base -> cup."""
    centre = grasp_point(cup_position)
    base_dir = math.atan2(centre[1], centre[0])
    for az in azimuths_deg:
        a = base_dir + math.radians(az)
        u = np.array([math.cos(a), math.sin(a), 0.0])
        yield centre - standoff * u, orientation_from_axes(u, (0, 0, 1))


def nearest_equivalent(g, j, lower, upper) -> np.ndarray:
    """``g`` with each continuous joint shifted by the multiple of 2 pi that brings it nearest to ``j`` within the
    limits, and left as it is where no shifted copy is within them. |g + 2 pi k - j| is convex in k, so the best k
    is the unconstrained round((j - g) / 2 pi), clipped to the range of k that keeps g + 2 pi k within the limits."""
    g = np.array(g, dtype=np.float64)
    j, lower, upper = (np.asarray(x, dtype=np.float64) for x in (j, lower, upper))
    turn = 2 * math.pi
    k_min, k_max = np.ceil((lower - g) / turn), np.floor((upper - g) / turn)
    k = np.clip(np.round((j - g) / turn), k_min, k_max)
    return np.where(CONTINUOUS & (k_min <= k_max), g + k * turn, g)


def nearest_goal(G: np.ndarray, j: np.ndarray, lower, upper) -> np.ndarray:
    """Eq. 9: g*(s) = argmin_{g in G} |g - j(s)|_1 (continuous joints taken modulo 2 pi)."""
    eq = np.array([nearest_equivalent(g, j, lower, upper) for g in G])
    return eq[int(np.argmin(np.abs(eq - j).sum(axis=1)))]


def step_towards(goal: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Eq. 10 with the overshoot fix: (pi/5) (g* - j) / max_i |g*_i - j_i|, but never past g*."""
    diff = goal - j
    largest = float(np.max(np.abs(diff)))
    if largest == 0.0:
        return np.zeros_like(diff)
    return diff * min(1.0, MAX_DELTA / largest)


@dataclass
class IKExpert:
    """pi_exp for one episode of a Jaco environment: call :meth:`reset` after ``env.reset`` (it builds G for the
    episode's cup), then :meth:`action` for any state of that episode. The action is a function of the state alone
    (eq. 8 pairs each state with pi_exp(s)): the joint angles and the cup (through G) decide it, never the states
    visited before. For grasping (Section V-B) the expert follows eqs. 9-10 towards pre-grasp poses d_g away from the
    cup and, once the hand is near the grasp point and points at it, heads for the grasp configuration of
    :meth:`final_goal` instead. That IK is solved afresh in every such state, so two visits of the same state get the
    same label."""

    env: JacoEnv

    def __post_init__(self):
        self.scene: JacoScene = self.env.unwrapped.scene
        self.grasping = isinstance(self.env.unwrapped, JacoGraspEnv)
        self.G = np.empty((0, N_JOINTS))

    def reset(self) -> np.ndarray:
        """Build G for the current cup (the env must have been reset). Returns G."""
        cup = self.scene.cup_position
        self.G = solution_set(self.scene, grasp_targets(cup) if self.grasping else reach_targets(cup))
        return self.G

    def goal(self, joints=None) -> np.ndarray | None:
        """g*(s) for the state with joint angles ``joints`` (default: the env's current ones): the final grasp
        configuration in the grasping task's final approach, else eq. 9's nearest member of G; None if G is empty."""
        j = self.scene.joints.copy() if joints is None else np.asarray(joints, dtype=np.float64)
        if len(self.G) == 0:
            return None
        final = self.final_goal(j) if self.grasping else None
        return final if final is not None else nearest_goal(self.G, j, self.scene.lower, self.scene.upper)

    def action(self, joints=None) -> np.ndarray:
        """pi_exp(s) (eq. 10) for the state whose joint angles are ``joints`` (default: the env's current ones)."""
        j = self.scene.joints.copy() if joints is None else np.asarray(joints, dtype=np.float64)
        goal = self.goal(j)
        return np.zeros(N_JOINTS) if goal is None else step_towards(goal, j)

    def final_goal(self, joints) -> np.ndarray | None:
        """Grasp phase (Section V-B): if the hand at ``joints`` is within :data:`FINAL_APPROACH_DISTANCE` of the grasp
        point and points at it (within :data:`FINAL_APPROACH_ANGLE_DEG`), the IK answer from ``joints`` for the grasp
        point at the current hand orientation; None otherwise, or if that answer is invalid or in collision."""
        j = np.asarray(joints, dtype=np.float64)
        saved = self.scene.joints.copy()
        self.scene.set_joints(j)
        tcp, orientation = self.scene.tcp_frame()
        self.scene.set_joints(saved)
        approach = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)[:, 2]
        target = grasp_point(self.scene.cup_position)
        to_cup = target - tcp
        dist = float(np.linalg.norm(to_cup))
        if dist > FINAL_APPROACH_DISTANCE:
            return None
        off_axis = math.degrees(math.acos(float(np.clip(np.dot(approach, to_cup / max(dist, 1e-12)), -1, 1))))
        if dist > 1e-3 and off_axis > FINAL_APPROACH_ANGLE_DEG:
            return None
        return solve_ik(self.scene, target, orientation, j)
