"""The CPU vector kernels of torch and numpy, pinned to AVX2 so that results regenerate on any x86-64 CPU.

torch (ATen's element-wise and reduction kernels, oneDNN's convolutions) and numpy's OpenBLAS choose
their SIMD code path from the CPU they run on. On a CPU with AVX-512 they take 512-bit kernels, which add
in a different order than the AVX2 kernels and so round differently in the last bits. TRPO amplifies such
bits within a few iterations. Measured on an AVX-512 machine (AMD EPYC) against the shipped rows, which
were made with AVX2 kernels: the first TRPO iterations of the shipped Fig. 4-7 runs differ by up to 5e-4
relative (``mean_kl``), and the losses of the first image pre-training epoch by up to 1.4e-4 relative
(``val_loglik``). With the three settings below the same runs match the shipped rows bit for bit there; on
an Intel Xeon with AVX-512 they still differ by up to 5.7e-4 relative (torch's BLAS rounds differently on it,
measured 2026-12-02), which ``tests/test_regeneration.py`` detects and compares within a stated tolerance.

So on a CPU that has AVX2 the package selects the AVX2 kernels before torch or numpy load (``import
vdtutorial`` does it first). The variables are only set where the user has not set them, and
``VDTUTORIAL_NATIVE_KERNELS=1`` keeps the CPU's own kernels (no longer the shipped numbers to the last
bit). The CPU's flags are read from ``/proc/cpuinfo``: elsewhere (macOS, Windows) and on other
architectures nothing is pinned, since forcing AVX2 on a CPU without it would stop the process.

Taught in chapter 04.
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
NATIVE_ENV = "VDTUTORIAL_NATIVE_KERNELS"


def cpu_flags(path: str = "/proc/cpuinfo") -> set[str]:
    """The CPU's feature flags as Linux lists them (empty where there is no such file)."""
    try:
        with open(path) as f:
            return next((set(line.split(":", 1)[1].split()) for line in f if line.startswith("flags")), set())
    except OSError:
        return set()


def pin_vector_kernels(environ=os.environ, flags: set[str] | None = None) -> dict[str, str]:
    """Set the variables of :data:`PINNED` in ``environ`` where they are unset, on an x86-64 CPU with AVX2
    (``flags``: :func:`cpu_flags`) unless ``VDTUTORIAL_NATIVE_KERNELS=1``; return those it set. Child
    processes (the experiments' worker pool, notebook kernels) inherit them. If numpy was loaded before
    this ran, its OpenBLAS has already chosen; on an AVX-512 CPU a warning says so."""
    flags = cpu_flags() if flags is None else flags
    if platform.machine().lower() not in ("x86_64", "amd64") or "avx2" not in flags or environ.get(NATIVE_ENV) == "1":
        return {}
    added = {name: value for name, value in PINNED.items() if name not in environ}
    environ.update(added)
    if "OPENBLAS_CORETYPE" in added and "numpy" in sys.modules and "avx512f" in flags:
        warnings.warn("numpy was imported before vdtutorial, so its OpenBLAS uses this CPU's AVX-512 kernels: "
                      "results may differ from the shipped ones in the last digits. Import vdtutorial first, "
                      "or set OPENBLAS_CORETYPE=Haswell before starting Python.", stacklevel=3)
    return added


def kernel_settings() -> dict[str, str]:
    """What an experiment record notes about the kernels: torch's CPU capability in use, and the variables."""
    import torch

    return {"torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            **{name: os.environ.get(name, "") for name in (*PINNED, NATIVE_ENV)}}
