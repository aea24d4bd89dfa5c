"""The one place where the package reads the quick switch.

``VDTUTORIAL_QUICK=1`` (set by CI) shrinks every budget -- samples, epochs, seeds, RL steps -- so that
a run goes through the same code path end to end in seconds instead of hours. Library code never reads
the environment variable itself: it calls :func:`budget` with the full-scale value and the quick one, when a
run starts (never when a module is imported), so that :func:`use_quick` reaches every run made after it.

Taught in chapter 00.
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


#: The file that marks a folder written by ``python -m vdtutorial notebooks DEST`` (:mod:`vdtutorial.chapters`).
BOOK_RECORD = "vdtutorial-book.json"
_PACKAGE = Path(__file__).resolve().parent
#: The copy of the chapters and data inside an installed package (the wheel carries them there).
_INSTALLED_COPY = _PACKAGE / "book"


def _shipped_dir() -> Path:
    """Where the shipped chapters and data are: the source checkout this package was imported from (its
    ``notebooks/`` and ``data/``), else the copy inside the installed package (a wheel carries them as
    ``vdtutorial/book``)."""
    checkout = _PACKAGE.parent
    if (checkout / "pyproject.toml").is_file() and (checkout / "data").is_dir():
        return checkout
    return _INSTALLED_COPY


#: The folder holding the shipped ``notebooks/`` and ``data/`` (read only: ``notebooks DEST`` copies them out).
SHIPPED_DIR = _shipped_dir()


def _project_dir() -> Path:
    """The folder that holds ``data/`` (and ``notebooks/``, ``runs/``): the folder written by ``python -m
    vdtutorial notebooks DEST`` that contains the working directory, if any, so that chapters run from such
    a copy read and write there; else :data:`SHIPPED_DIR`."""
    here = Path.cwd()
    return next((folder for folder in (here, *here.parents) if (folder / BOOK_RECORD).is_file()), SHIPPED_DIR)


PROJECT_DIR = _project_dir()
#: Where shipped and generated artefacts live (demonstrations, checkpoints, result CSVs): ``data/`` in
#: :data:`PROJECT_DIR`, or the folder named by ``VDTUTORIAL_DATA``.
DATA_DIR = Path(os.environ.get("VDTUTORIAL_DATA", PROJECT_DIR / "data"))

#: Where commands write what they make unless told otherwise (``--out``): ``runs/`` beside ``data/``
#: (or the folder named by ``VDTUTORIAL_RUNS``), so that the shipped artefacts in ``data/`` are never
#: replaced by accident. When the package's own copy is all there is (an installed wheel used outside a
#: folder written by ``notebooks DEST``), nothing is written into the installation: ``runs/`` in the working
#: directory.
RUNS_DIR = Path(os.environ.get("VDTUTORIAL_RUNS", (Path.cwd() if PROJECT_DIR == _INSTALLED_COPY else PROJECT_DIR)
                               / "runs"))


def recorded_path(path) -> str:
    """``path`` as a record that may be shipped writes it (a result's JSON, a checkpoint's command): relative
    to the folder that holds ``data/`` when it is inside it (``data/demos/...``, ``runs/...``), so that a
    shipped file never names the machine that made it and its commands run from any clone or copy. A
    path outside that folder (a user's scratch folder) is written as given."""
    path, project = Path(path).resolve(), DATA_DIR.resolve().parent
    return path.relative_to(project).as_posix() if path.is_relative_to(project) else str(path)
