"""The one place where the package reads the quick switch.

``VDTUTORIAL_QUICK=1`` (set by CI) shrinks every budget -- samples, epochs, seeds, RL steps -- so that
a run goes through the same code path end to end in seconds instead of hours. Library code never reads
the environment variable itself: it calls :func:`budget` with the full-scale value and the quick one.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

#: The environment variable behind the switch (CI and ``classroom grade`` set it for the kernels they start).
QUICK_ENV = "VDTUTORIAL_QUICK"
QUICK: bool = os.environ.get(QUICK_ENV, "0").strip().lower() in {"1", "true", "yes"}
#: Modules that size budgets when they are imported: a switch made after them does not reach them.
_SIZED_AT_IMPORT = ("vdtutorial.experiments", "vdtutorial.pretrain")


def use_quick(on: bool | None) -> bool:
    """Switch quick mode from inside a notebook (its first code cell), so students need no environment
    variable before starting Jupyter. ``None`` keeps what the environment says (nbmake and CI runs).

    Call it before importing the rest of vdtutorial: some modules size their budgets at import. If one of
    them is already imported with the other setting, this says to restart the kernel instead of leaving a
    notebook half in one mode. The variable is set too, so worker processes follow. Returns the mode.
    """
    global QUICK
    if on is None or bool(on) == QUICK:
        return QUICK
    stale = [m for m in _SIZED_AT_IMPORT if m in sys.modules]
    if stale:
        print(f"quick mode stays {'ON' if QUICK else 'off'}: {stale[0]} was imported before the switch; "
              "restart the kernel and run the notebook from the top")
        return QUICK
    QUICK = bool(on)
    os.environ[QUICK_ENV] = "1" if QUICK else "0"
    return QUICK


def budget(full, quick):
    """Return ``quick`` when quick mode is on, else ``full`` (the paper's setting)."""
    return quick if QUICK else full


#: Where shipped and generated artefacts live (demonstrations, checkpoints, result CSVs): the
#: repository's ``data/`` folder, or the folder named by ``VDTUTORIAL_DATA``.
DATA_DIR = Path(os.environ.get("VDTUTORIAL_DATA", Path(__file__).resolve().parent.parent / "data"))

#: Where commands write what they make unless told otherwise (``--out``): ``runs/`` beside ``data/``
#: (or the folder named by ``VDTUTORIAL_RUNS``), so that the shipped artefacts in ``data/`` are never
#: replaced by accident.
RUNS_DIR = Path(os.environ.get("VDTUTORIAL_RUNS", DATA_DIR.parent / "runs"))
