"""The chapters as a learner takes them away: ``python -m vdtutorial notebooks DEST`` (chapter 00 shows it).

A ``pip install`` of the wheel carries the notebooks and the shipped data (``vdtutorial/book``), so no
clone is needed. This writes them into DEST as ``notebooks/`` and ``data/``, with a record file
(``settings.BOOK_RECORD``). A chapter run from DEST finds that record above its working directory, so it
reads ``DEST/data`` and writes ``DEST/runs`` (``settings.project_dir()``).

The record holds the hash of every file written. Writing again (say, after upgrading the package)
replaces the files the learner has not touched, and refuses, unless ``force``, when one of them was
edited: a learner's answers are never overwritten by accident.

``student=True`` writes the self-learner's edition: ``notebooks/`` holds the student edition, made by
nbgrader exactly as ``classroom release`` makes it (each exercise's solution replaced by a stub, hidden
tests removed), and the teacher's chapters, with the solutions, go to ``solutions/``: beside the exercises,
but opened only on purpose.

Taught in chapter 00.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import vdtutorial
from vdtutorial.settings import BOOK_RECORD, shipped_dir


class EditedFilesError(FileExistsError):
    """DEST holds files changed since they were written (or not written by us): not overwritten."""


class NoNbgraderError(ImportError):
    """The student edition needs nbgrader (the ``classroom`` extra), which is not installed."""


@dataclass(frozen=True)
class WrittenBook:
    """What :func:`write_notebooks` wrote: counts of chapters (``NN_*.ipynb``), appendices (``A1_*.ipynb``, no
    exercises: the same in both editions), data files and, in the student edition, solution notebooks."""

    dest: Path
    chapters: int
    data_files: int
    solutions: int = 0
    appendices: int = 0


#: What an experiment writes beside its results while it runs (its per-run logs, saved states, the checkpoints and
#: the data sets it made, locks): never shipped, so never copied out or packed. Some are committed (a grid's states,
#: the beyond experiment's data sets) so that a rerun of its command continues rather than starts again; the results
#: themselves (NAME.csv.gz, NAME.json, NAME.png) hold everything a chapter reads. A record made from other experiments'
#: folders keeps their rows under ``rows`` (the ablations': its JSON holds every number it reports).
_SCRATCH = ("runs", "state", "checkpoints", "demos", "rows")


def _shipped_data(path: Path, data: Path) -> bool:
    parts = path.relative_to(data).parts
    scratch = parts[0] == "results" and len(parts) > 3 and parts[2] in _SCRATCH
    return path.is_file() and not scratch and path.suffix not in (".lock", ".tmp")


def shipped_files(source: Path | None = None) -> list[Path]:
    """What a learner's copy holds, relative to ``source`` (default: :func:`~vdtutorial.settings.shipped_dir`):
    the chapters and the teaching notes, and every shipped data file (demonstrations, checkpoints, results)
    they load."""
    source = Path(source) if source is not None else shipped_dir()
    chapters = sorted((source / "notebooks").glob("*.ipynb")) + sorted((source / "notebooks").glob("*.md"))
    data = sorted(p for p in (source / "data").rglob("*") if _shipped_data(p, source / "data"))
    if not chapters or not data:
        raise FileNotFoundError(f"{source} holds no notebooks/ or data/: this installation carries no chapters")
    return [p.relative_to(source) for p in chapters + data]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _student_edition(files: dict[str, Path], source: Path, scratch: Path) -> dict[str, Path]:
    """``files`` with each chapter replaced by its student edition (released by nbgrader into ``scratch``) and
    the teacher's chapter moved to ``solutions/``."""
    if importlib.util.find_spec("nbgrader") is None:
        raise NoNbgraderError(
            "the student edition is made by nbgrader, which is not installed: pip install 'vdtutorial[classroom]'"
        )
    from vdtutorial.course.classroom import release

    files = dict(files)
    for released in release(scratch, source / "notebooks"):
        files[f"solutions/{released.name}"] = files[f"notebooks/{released.name}"]
        files[f"notebooks/{released.name}"] = released
    return files


def write_notebooks(
    dest: str | Path, force: bool = False, source: Path | None = None, student: bool = False
) -> WrittenBook:
    """Copy the chapters and their data from ``source`` into ``dest``; with ``student``, the student edition
    and its solutions apart (module docstring, "writes the self-learner's edition").

    Raises :class:`EditedFilesError`, before writing anything, if a file to be replaced differs both from
    what was last written there and from what would be written now, unless ``force``."""
    dest, source = Path(dest), Path(source) if source is not None else shipped_dir()
    if dest.exists() and not dest.is_dir():
        raise NotADirectoryError(f"{dest} is a file, not a folder: name a folder for the chapters")
    record_path = dest / BOOK_RECORD
    written = json.loads(record_path.read_text())["files"] if record_path.is_file() else {}
    with tempfile.TemporaryDirectory(prefix="vdtutorial_edition_") as scratch:
        files = {path.as_posix(): source / path for path in shipped_files(source)}
        if student:
            files = _student_edition(files, source, Path(scratch))
        digests = {name: _digest(path) for name, path in files.items()}
        edited = [
            name
            for name in digests
            if (dest / name).is_file() and _digest(dest / name) not in (written.get(name), digests[name])
        ]
        if edited and not force:
            raise EditedFilesError(
                f"{dest} holds {len(edited)} file(s) changed since they were written, e.g. "
                f"{edited[0]}: pass --force to overwrite them, or name another folder"
            )
        for name, path in files.items():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, dest / name)
    record = {"vdtutorial": vdtutorial.__version__, "files": digests}
    record_path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    notebooks = [name.split("/", 1)[1] for name in digests if name.startswith("notebooks/") and name.endswith(".ipynb")]
    return WrittenBook(
        dest,
        sum(name[:2].isdigit() for name in notebooks),
        sum(name.startswith("data/") for name in digests),
        sum(name.startswith("solutions/") for name in digests),
        sum(name[0] == "A" and name[1].isdigit() for name in notebooks),
    )
