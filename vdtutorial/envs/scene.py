"""The pybullet world shared by both tasks: a table, the Jaco-like arm, a cup and a fixed RGBD camera.

The scene is kinematic: joint angles are set directly (``resetJointState``) and pybullet's collision detection finds
collisions, with no dynamics integrated. The paper's V-REP setup commands joint-angle deltas and treats the motion as
exact ("transition dynamics ... assumed to have very small variance", Section IV), so a kinematic world models the same
MDP and runs several thousand steps per second on a laptop core, unlike a dynamic simulation with position controllers.

Units are metres and radians. The world origin is the arm's base on the table top (z = 0).

Taught in chapter 01.
"""

from __future__ import annotations

import functools
import math
import struct
from importlib import resources

import numpy as np
from vdtutorial.envs.bullet import pybullet as p
from vdtutorial.envs.bullet import warn_if_images_are_slow

#: Kinova's "home" pose of the Jaco 2 6-DOF in Kinova's joint convention (degrees), the start pose.
HOME_DEG = (275.0, 167.5, 57.5, 240.0, 82.5, 75.0)
HOME = np.radians(HOME_DEG)
#: Links of the arm (pybullet indices). -1 is the base.
LINKS = {"base": -1, "link1": 0, "link2": 1, "link3": 2, "link4": 3, "link5": 4, "link6": 5, "hand": 6, "tcp": 7}
N_JOINTS = 6
#: Pairs of arm links whose collision counts as self-collision. Links that touch by construction
#: (neighbours, and the links of the curved wrist, which overlap at every pose) are excluded.
SELF_COLLISION_PAIRS = tuple(
    (LINKS[a], LINKS[b]) for a in ("base", "link1") for b in ("link4", "link5", "link6", "hand")
) + tuple((LINKS["link2"], LINKS[b]) for b in ("link5", "link6", "hand"))

TABLE_HALF_EXTENTS = (0.55, 0.6, 0.02)
TABLE_CENTRE = (0.3, 0.0, -0.02)
CUP_RADIUS = 0.035
CUP_HEIGHT = 0.12
#: Region p0 of cup positions on the table (uniform), in front of the arm and within its reach.
CUP_REGION_LOW = np.array([0.30, -0.25])
CUP_REGION_HIGH = np.array([0.60, 0.25])

#: Camera: a fixed pose looking at the table and the arm from the front right.
CAMERA_EYE = (1.35, 0.65, 0.95)
CAMERA_TARGET = (0.25, 0.0, 0.25)
CAMERA_FOV_DEG = 55.0
CAMERA_NEAR, CAMERA_FAR = 0.1, 3.0


def arm_urdf_path() -> str:
    """Path of the shipped arm URDF (primitive shapes, Jaco 2 link lengths and joint limits)."""
    return str(resources.files("vdtutorial") / "assets" / "jaco6.urdf")


@functools.cache
def _c_floats(n: int) -> struct.Struct:
    return struct.Struct(f"{n}f")


def camera_buffers(rgba, zbuf) -> tuple[np.ndarray, np.ndarray]:
    """Flat uint8 and float32 arrays of ``pybullet.getCameraImage``'s RGBA and z-buffer from a pybullet without numpy
    support (e.g. a source build in pip's isolated environment), which gives them as Python int and float sequences.

    numpy converts such sequences one element at a time (``np.asarray``, ``np.fromiter``); C buffers are cheaper:
    ``bytearray`` packs the 0-255 ints into bytes, ``struct`` packs the floats as C floats, and numpy wraps the bytes
    without another pass. The values are identical bit for bit: pybullet's colours are bytes and its depths C floats
    widened to Python floats, so narrowing them back to float32 is exact. The z-buffer's array is read-only
    (:meth:`JacoScene.render_rgbd` only reads it).
    """
    return (
        np.frombuffer(bytearray(rgba), dtype=np.uint8),
        np.frombuffer(_c_floats(len(zbuf)).pack(*zbuf), dtype=np.float32),
    )


class JacoScene:
    """Owns one pybullet client (DIRECT, no GUI) and the bodies of the scene, by name.

    Parameters
    ----------
    image_size: side of the square camera image in pixels (128 for reaching, 256 for grasping in the paper).
    cup_collidable: whether the cup has a collision shape: not in reaching (Section V-A), in grasping (Section V-B).
    cup_radius: in metres (grasping's narrower cup fits between the open fingers, see :mod:`vdtutorial.envs.grasp`).
    """

    def __init__(self, image_size: int = 128, cup_collidable: bool = False, cup_radius: float = CUP_RADIUS):
        if int(image_size) != image_size or image_size < 16:
            raise ValueError(f"image_size must be an integer >= 16, got {image_size!r}")
        self.image_size = int(image_size)
        self.cup_collidable = cup_collidable
        self.cup_radius = float(cup_radius)
        self.client = p.connect(p.DIRECT)
        c = self.client
        table_col = p.createCollisionShape(p.GEOM_BOX, halfExtents=TABLE_HALF_EXTENTS, physicsClientId=c)
        table_vis = p.createVisualShape(
            p.GEOM_BOX, halfExtents=TABLE_HALF_EXTENTS, rgbaColor=(0.72, 0.58, 0.42, 1), physicsClientId=c
        )
        self.table = p.createMultiBody(0, table_col, table_vis, basePosition=TABLE_CENTRE, physicsClientId=c)
        # The arm faces +x: Kinova's base frame has the home pose reaching towards -y, so turn it by 90 deg.
        self.arm = p.loadURDF(
            arm_urdf_path(),
            basePosition=(0, 0, 0),
            baseOrientation=p.getQuaternionFromEuler((0, 0, math.pi / 2)),
            useFixedBase=True,
            flags=p.URDF_USE_SELF_COLLISION,
            physicsClientId=c,
        )
        cup_col = (
            p.createCollisionShape(p.GEOM_CYLINDER, radius=cup_radius, height=CUP_HEIGHT, physicsClientId=c)
            if cup_collidable
            else -1
        )
        cup_vis = p.createVisualShape(
            p.GEOM_CYLINDER, radius=cup_radius, length=CUP_HEIGHT, rgbaColor=(0.85, 0.2, 0.15, 1), physicsClientId=c
        )
        self.cup = p.createMultiBody(0, cup_col, cup_vis, basePosition=(0.45, 0, CUP_HEIGHT / 2), physicsClientId=c)
        self.bodies = {"table": self.table, "arm": self.arm, "cup": self.cup}
        self._restrict_collisions()
        info = [p.getJointInfo(self.arm, j, physicsClientId=c) for j in range(N_JOINTS)]
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])
        self._view = p.computeViewMatrix(CAMERA_EYE, CAMERA_TARGET, (0, 0, 1), physicsClientId=c)
        self._proj = p.computeProjectionMatrixFOV(CAMERA_FOV_DEG, 1.0, CAMERA_NEAR, CAMERA_FAR, physicsClientId=c)
        self.joints = HOME.copy()
        self.cup_position = np.array([0.45, 0.0, 0.0])
        self.set_joints(HOME)

    # -- collision filtering -------------------------------------------------------------------------
    def _restrict_collisions(self) -> None:
        """Keep only the contacts that mean failure: arm vs table (not the base, which stands on it),
        arm vs cup, and the self-collision pairs of :data:`SELF_COLLISION_PAIRS`."""
        c = self.client
        links = range(-1, p.getNumJoints(self.arm, physicsClientId=c))
        wanted = {frozenset(pair) for pair in SELF_COLLISION_PAIRS}
        for a in links:
            for b in links:
                if a < b and frozenset((a, b)) not in wanted:
                    p.setCollisionFilterPair(self.arm, self.arm, a, b, 0, physicsClientId=c)
        p.setCollisionFilterPair(self.arm, self.table, LINKS["base"], -1, 0, physicsClientId=c)
        p.setCollisionFilterPair(self.cup, self.table, -1, -1, 0, physicsClientId=c)

    # -- state ---------------------------------------------------------------------------------------
    def set_joints(self, q) -> None:
        """Put the arm at joint angles ``q`` (Kinova convention, radians)."""
        for j in range(N_JOINTS):
            p.resetJointState(self.arm, j, float(q[j]), physicsClientId=self.client)
        self.joints = np.array(q, dtype=np.float64)

    def set_cup(self, xy) -> None:
        """Stand the cup on the table with its base centre at ``(x, y, 0)``."""
        x, y = float(xy[0]), float(xy[1])
        p.resetBasePositionAndOrientation(self.cup, (x, y, CUP_HEIGHT / 2), (0, 0, 0, 1), physicsClientId=self.client)
        self.cup_position = np.array([x, y, 0.0])

    def tcp_frame(self) -> tuple[np.ndarray, tuple]:
        """World position and orientation (quaternion x, y, z, w) of the hand centre's frame."""
        state = p.getLinkState(self.arm, LINKS["tcp"], computeForwardKinematics=True, physicsClientId=self.client)
        return np.array(state[4]), state[5]

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position of the hand centre and the hand's approach axis (unit vector, the frame's z)."""
        position, orientation = self.tcp_frame()
        return position, np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)[:, 2]

    def in_collision(self) -> bool:
        """Whether the arm, at its current joints, touches the table, the cup (if collidable) or itself."""
        p.performCollisionDetection(physicsClientId=self.client)
        return len(p.getContactPoints(bodyA=self.arm, physicsClientId=self.client)) > 0

    def path_in_collision(self, q_from, q_to, max_joint_step: float = 0.2) -> bool:
        """Check the straight joint-space motion from ``q_from`` to ``q_to`` at sub-steps of at most ``max_joint_step``
        radians per joint, so that a large action cannot jump through the table. Leaves the arm at ``q_to``."""
        q_from, q_to = np.asarray(q_from, float), np.asarray(q_to, float)
        n = max(1, int(math.ceil(np.max(np.abs(q_to - q_from)) / max_joint_step)))
        for k in range(1, n + 1):
            self.set_joints(q_from + (q_to - q_from) * (k / n))
            if self.in_collision():
                self.set_joints(q_to)
                return True
        return False

    # -- camera --------------------------------------------------------------------------------------
    def render_rgbd(self) -> tuple[np.ndarray, np.ndarray]:
        """RGB (uint8, H x W x 3) and depth in metres (float32, H x W) from the fixed camera: TinyRenderer, no shadows
        and no segmentation mask, the cheapest image pybullet makes without a GPU. The z-buffer is turned into metric
        depth with the projection's near/far planes."""
        warn_if_images_are_slow()
        s = self.image_size
        _, _, rgba, zbuf, _ = p.getCameraImage(
            s,
            s,
            self._view,
            self._proj,
            shadow=0,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client,
        )
        if not isinstance(rgba, np.ndarray):  # pybullet without numpy support: flat tuples
            rgba, zbuf = camera_buffers(rgba, zbuf)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(s, s, 4)
        zbuf = np.asarray(zbuf, dtype=np.float32).reshape(s, s)
        depth = CAMERA_FAR * CAMERA_NEAR / (CAMERA_FAR - (CAMERA_FAR - CAMERA_NEAR) * zbuf)
        return rgba[..., :3], depth.astype(np.float32)

    def close(self) -> None:
        """Disconnect the client; safe to call more than once."""
        if self.client is not None:
            if p.isConnected(self.client):
                p.disconnect(self.client)
            self.client = None
