"""vdtutorial: rebuild "Improving Reinforcement Learning Pre-Training with Variational Dropout"
(Blau, Ott, Ramos, IROS 2018) piece by piece, on a laptop CPU.

Pipeline: IK expert -> noisy demonstrations -> behavioural cloning with sparse variational dropout
(or L2) -> pruning (log alpha > 3) -> TRPO fine-tuning. Importing the package registers the
gymnasium environments ``vdtutorial/JacoReach-v0`` and ``vdtutorial/JacoGrasp-v0``, after pinning
torch's and numpy's CPU kernels to AVX2 (:mod:`vdtutorial.kernels`: the shipped results then regenerate
bit for bit on the x86-64 CPUs measured, not all of them), which must happen before numpy loads.

Taught in chapter 00.
"""
__version__ = "0.1.0"

from vdtutorial.kernels import pin_vector_kernels as _pin_vector_kernels  # noqa: E402  (stdlib only)

_pin_vector_kernels()

from vdtutorial import envs as _envs  # noqa: E402,F401  (registers the environment ids)
