"""Where commands write what they make, and how a record that may be shipped names a file.

Both are looked up on every call (like :mod:`vdtutorial.settings`), so a changed working directory or
``VDTUTORIAL_RUNS`` reaches the next command run in the same kernel.

Not taught in a chapter: file-system plumbing of the commands and the shipped records.
"""

from __future__ import annotations

import os
from pathlib import Path

from vdtutorial.settings import INSTALLED_COPY, data_dir, project_dir

#: The variable that moves the output folder elsewhere.
RUNS_ENV = "VDTUTORIAL_RUNS"


def runs_dir() -> Path:
    """Where commands write what they make unless told otherwise (``--out``): ``runs/`` beside ``data/`` (or
    the folder named by ``VDTUTORIAL_RUNS``), so that the shipped artefacts in ``data/`` are never replaced by
    accident. When the package's own copy is all there is (an installed wheel used outside a folder written by
    ``notebooks DEST``), nothing is written into the installation: ``runs/`` in the working directory."""
    if RUNS_ENV in os.environ:
        return Path(os.environ[RUNS_ENV])
    project = project_dir()
    return (Path.cwd() if project == INSTALLED_COPY else project) / "runs"


def recorded_path(path) -> str:
    """``path`` as a record that may be shipped writes it (a result's JSON, a checkpoint's command): relative
    to the folder that holds ``data/`` when it is inside it (``data/demos/...``, ``runs/...``), so that a
    shipped file never names the machine that made it and its commands run from any clone or copy. A
    path outside that folder (a user's scratch folder) is written as given.

    The path is looked at as written before its links are followed: a ``runs/`` that links to another disk,
    or to the checkout a worktree shares it with, is still ``runs/...`` to the commands that ran in it."""
    data = data_dir()
    as_written = (Path(os.path.abspath(path)), Path(os.path.abspath(data)).parent)
    resolved = (Path(path).resolve(), data.resolve().parent)
    for candidate, project in (as_written, resolved):
        if candidate.is_relative_to(project):
            return candidate.relative_to(project).as_posix()
    return str(resolved[0])
