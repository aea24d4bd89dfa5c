"""The one place where the package reads the quick switch.

``VDTUTORIAL_QUICK=1`` (set by CI) shrinks every budget -- samples, epochs, seeds, RL steps -- so that
a run goes through the same code path end to end in seconds instead of hours. Library code never reads
the environment variable itself: it calls :func:`budget` with the full-scale value and the quick one, when a
run starts (never when a module is imported), so that :func:`use_quick` reaches every run made after it.
"""
from __future__ import annotations

import os
from pathlib import Path

#: The environment variable behind the switch (CI and ``classroom grade`` set it for the kernels they start).
QUICK_ENV = "VDTUTORIAL_QUICK"
#: The mode now: read it through :func:`is_quick` (a name imported from here keeps the value it had then).
QUICK: bool = os.environ.get(QUICK_ENV, "0").strip().lower() in {"1", "true", "yes"}


def use_quick(on: bool | None) -> bool:
    """Switch quick mode from inside a notebook (its first code cell), so students need no environment
    variable before starting Jupyter. ``None`` keeps what the environment says (nbmake and CI runs).

    Every budget is looked up when a run starts, so the switch reaches every run made after it, whatever
    was imported before. The variable is set too, so worker processes follow. Returns the mode.
    """
    global QUICK
    if on is not None:
        QUICK = bool(on)
        os.environ[QUICK_ENV] = "1" if QUICK else "0"
    return QUICK


def is_quick() -> bool:
    """Whether quick mode is on at this moment (after any :func:`use_quick`)."""
    return QUICK


def budget(full, quick):
    """Return ``quick`` when quick mode is on, else ``full`` (the paper's setting). Call it when a run
    starts, not at import, so that a later :func:`use_quick` is obeyed."""
    return quick if QUICK else full


#: Where shipped and generated artefacts live (demonstrations, checkpoints, result CSVs): the
#: repository's ``data/`` folder, or the folder named by ``VDTUTORIAL_DATA``.
DATA_DIR = Path(os.environ.get("VDTUTORIAL_DATA", Path(__file__).resolve().parent.parent / "data"))

#: Where commands write what they make unless told otherwise (``--out``): ``runs/`` beside ``data/``
#: (or the folder named by ``VDTUTORIAL_RUNS``), so that the shipped artefacts in ``data/`` are never
#: replaced by accident.
RUNS_DIR = Path(os.environ.get("VDTUTORIAL_RUNS", DATA_DIR.parent / "runs"))
