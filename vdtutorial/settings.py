"""The quick switch and the data folder, each read when a run asks for it.

``VDTUTORIAL_QUICK=1`` (set by CI) shrinks every budget -- samples, epochs, seeds, RL steps -- so that a run goes
through the same code path end to end in seconds instead of hours. Library code never reads the variable itself: it
calls :func:`budget` with the full-scale value and the quick one when a run starts. Nothing is decided at import,
so :func:`use_quick` (or a changed working directory or variable) reaches every run made after it, in the same kernel.

Taught in chapter 00.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The environment variable behind the switch (CI and ``classroom grade`` set it for the kernels they start).
QUICK_ENV = "VDTUTORIAL_QUICK"
#: The variable that moves the data folder elsewhere.
DATA_ENV = "VDTUTORIAL_DATA"
#: The file that marks a folder written by ``python -m vdtutorial notebooks DEST`` (:mod:`vdtutorial.course.chapters`).
BOOK_RECORD = "vdtutorial-book.json"
_PACKAGE = Path(__file__).resolve().parent
#: The copy of the chapters and data inside an installed package (the wheel carries them there).
INSTALLED_COPY = _PACKAGE / "book"


def is_quick() -> bool:
    """Whether quick mode is on at this moment: the variable :data:`QUICK_ENV` as it is now."""
    return os.environ.get(QUICK_ENV, "0").strip().lower() in {"1", "true", "yes"}


def use_quick(on: bool | None) -> bool:
    """Switch quick mode from inside a notebook (``None`` keeps what the environment says); returns the mode. The
    switch is the variable itself, so worker processes started later follow it, and every budget asked for after
    this call obeys it: re-run a chapter's cells and they take the new sizes."""
    if on is not None:
        os.environ[QUICK_ENV] = "1" if on else "0"
    return is_quick()


def budget(full, quick):
    """Return ``quick`` when quick mode is on, else ``full`` (the paper's setting). Call it when a run
    starts, not at import, so that a later :func:`use_quick` is obeyed."""
    return quick if is_quick() else full


def shipped_dir() -> Path:
    """Where the shipped chapters and data are (read only: ``notebooks DEST`` copies them out): the source
    checkout this package was imported from (its ``notebooks/`` and ``data/``), else the copy inside the
    installed package (a wheel carries them as ``vdtutorial/book``)."""
    checkout = _PACKAGE.parent
    if (checkout / "pyproject.toml").is_file() and (checkout / "data").is_dir():
        return checkout
    return INSTALLED_COPY


def project_dir() -> Path:
    """The folder that holds ``data/`` (and ``notebooks/``, ``runs/``): the folder written by ``python -m
    vdtutorial notebooks DEST`` that contains the working directory, if any, so that chapters run from such
    a copy read and write there; else :func:`shipped_dir`."""
    here = Path.cwd()
    return next((folder for folder in (here, *here.parents) if (folder / BOOK_RECORD).is_file()), shipped_dir())


def data_dir() -> Path:
    """Where shipped and generated artefacts live (demonstrations, checkpoints, result CSVs): ``data/`` in
    :func:`project_dir`, or the folder named by ``VDTUTORIAL_DATA``."""
    return Path(os.environ.get(DATA_ENV, project_dir() / "data"))
