"""The CPU vector kernels of torch and numpy, pinned to AVX2 when a run must repeat the shipped numbers bit for bit.

torch (ATen's element-wise and reduction kernels, oneDNN's convolutions) and numpy's OpenBLAS choose
their SIMD code path from the CPU they run on. On a CPU with AVX-512 they take 512-bit kernels, which add
in a different order than the AVX2 kernels the shipped results were made with, and so round differently in
the last bits; TRPO amplifies such bits within a few iterations (docs/results.md, "Regenerable results, and
what determinism covers", has the sizes and the CPUs where the pins are not enough).

Nothing is pinned unless asked: ``import vdtutorial`` leaves ``os.environ`` alone, and a learner's notebook
runs on the CPU's own (fastest) kernels. Exact re-runs ask: ``python -m vdtutorial experiment|reproduce|
pretrain|bench ... --exact-kernels`` sets the variables and starts the command again (numpy has loaded by the
time arguments are parsed, and OpenBLAS chooses when it loads); the test suite sets them in its conftest,
before numpy loads; worker processes inherit them. The CPU's flags are read from ``/proc/cpuinfo``: elsewhere
(macOS, Windows) and on other architectures nothing is pinned, since forcing AVX2 on a CPU without it would
stop the process.

Taught in chapter 04. Stdlib only (torch is imported inside :func:`kernel_settings`), so that it can run before
numpy loads.
"""

from __future__ import annotations

import os
import platform
import sys
import warnings

#: The variables, each read by its library when it first needs them: ATen (torch's CPU kernels, read at the
#: first operation), oneDNN (torch's convolutions, read at the first convolution) and OpenBLAS (numpy's
#: linear algebra, read when numpy loads, hence "before numpy").
PINNED = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "OPENBLAS_CORETYPE": "Haswell"}


def cpu_flags(path: str = "/proc/cpuinfo") -> set[str]:
    """The CPU's feature flags as Linux lists them (empty where there is no such file)."""
    try:
        with open(path) as f:
            return next((set(line.split(":", 1)[1].split()) for line in f if line.startswith("flags")), set())
    except OSError:
        return set()


def cpu_model(path: str = "/proc/cpuinfo") -> str:
    """The CPU's model name as Linux lists it (``platform.processor()`` where there is no such file; empty if
    neither says). Recorded beside the kernels because the variables do not name the machine: torch's BLAS (MKL)
    picks its code path by CPU vendor as well as by vector width, so an Intel and an AMD CPU with the same
    recorded kernels can still round differently (docs/results.md, "Regenerable results")."""
    try:
        with open(path) as f:
            return next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        return platform.processor()


def can_pin(flags: set[str] | None = None) -> bool:
    """Whether this CPU runs the AVX2 kernels: an x86-64 CPU whose flags (:func:`cpu_flags`) include avx2."""
    flags = cpu_flags() if flags is None else flags
    return platform.machine().lower() in ("x86_64", "amd64") and "avx2" in flags


def pin_vector_kernels(environ=os.environ, flags: set[str] | None = None) -> dict[str, str]:
    """Set the variables of :data:`PINNED` in ``environ`` where they are unset, if :func:`can_pin`; return those it
    set. Call it before numpy loads, or on the environment of a new process: numpy's OpenBLAS chooses when it
    loads, so on an AVX-512 CPU a warning says when this process's numpy has already chosen."""
    flags = cpu_flags() if flags is None else flags
    if not can_pin(flags):
        return {}
    added = {name: value for name, value in PINNED.items() if name not in environ}
    environ.update(added)
    if "OPENBLAS_CORETYPE" in added and environ is os.environ and "numpy" in sys.modules and "avx512f" in flags:
        warnings.warn(
            "numpy was loaded before the kernels were pinned, so its OpenBLAS uses this CPU's AVX-512 "
            "kernels: results may differ from the shipped ones in the last digits. Pin them before "
            "numpy loads (the commands' --exact-kernels does), or set OPENBLAS_CORETYPE=Haswell "
            "before starting Python.",
            stacklevel=2,
        )
    return added


def pinned(environ=os.environ) -> bool:
    """Whether every variable of :data:`PINNED` is set in ``environ`` (to any value: the user's choice stands)."""
    return all(name in environ for name in PINNED)


def kernel_settings() -> dict[str, str]:
    """What an experiment record notes about the kernels: torch's CPU capability in use, the variables, and the
    CPU they ran on (:func:`cpu_model`)."""
    import torch

    return {
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        **{name: os.environ.get(name, "") for name in PINNED},
        "cpu": cpu_model(),
    }
