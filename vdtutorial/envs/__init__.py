"""Gymnasium environments of the paper's two tasks (Section V), registered on import.

``vdtutorial/JacoReach-v0``: put the gripper over a cup (eq. 11 reward).
``vdtutorial/JacoGrasp-v0``: put the open gripper around a cup that can be hit (sparse reward).
Both take ``obs_mode`` ("rgbd" or "state"), ``image_size`` and ``render_mode`` keywords.

Taught in chapter 01.
"""

import gymnasium

from vdtutorial.envs.base import HORIZON  # noqa: F401  (the horizon H, for the experiments and chapters)

ENV_IDS = {
    "reach": "vdtutorial/JacoReach-v0",
    "grasp": "vdtutorial/JacoGrasp-v0",
}

for _task, _entry in (("reach", "vdtutorial.envs.reach:JacoReachEnv"), ("grasp", "vdtutorial.envs.grasp:JacoGraspEnv")):
    if ENV_IDS[_task] not in gymnasium.registry:
        gymnasium.register(id=ENV_IDS[_task], entry_point=_entry)  # the env truncates at HORIZON itself
