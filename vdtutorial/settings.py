"""The one place where the package reads the quick switch.

``VDTUTORIAL_QUICK=1`` (set by CI) shrinks every budget -- samples, epochs, seeds, RL steps -- so that
a run goes through the same code path end to end in seconds instead of hours. Library code never reads
the environment variable itself: it calls :func:`budget` with the full-scale value and the quick one.
"""
from __future__ import annotations

import os
from pathlib import Path

QUICK: bool = os.environ.get("VDTUTORIAL_QUICK", "0").strip().lower() in {"1", "true", "yes"}


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
