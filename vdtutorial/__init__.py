"""vdtutorial: rebuild "Improving Reinforcement Learning Pre-Training with Variational Dropout"
(Blau, Ott, Ramos, IROS 2018) piece by piece, on a laptop CPU.

Pipeline: IK expert -> noisy demonstrations -> behavioural cloning with sparse variational dropout
(or L2) -> pruning (log alpha > 3) -> TRPO fine-tuning. Importing the package registers the
gymnasium environments ``vdtutorial/JacoReach-v0`` and ``vdtutorial/JacoGrasp-v0`` and changes nothing
else (no environment variable, no global setting).

Taught in chapter 00.
"""

__version__ = "0.1.0"

try:
    from vdtutorial import envs as _envs  # noqa: E402,F401  (registers the environment ids)
except ModuleNotFoundError as missing:  # say how to get pybullet on this machine, not just its name
    if missing.name != "pybullet":
        raise
    from vdtutorial.course.install_check import missing_pybullet

    raise ModuleNotFoundError(f"pybullet is not installed: {missing_pybullet()}", name="pybullet") from None
