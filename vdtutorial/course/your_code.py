"""A learner's answers from an earlier chapter, run again in a later one: the closing chapter's capstone trains with
the VD layer the learner wrote in chapter 04 and fine-tunes with the TRPO update they wrote in chapter 06b.

Each chapter runs on its own, so a later chapter cannot see the variables of an earlier one. What it can read is
the earlier notebook itself, as the learner saved it. :func:`load_answers` executes that notebook's setup cell
(its imports and constants) and then the chosen answer cells, in the notebook's order, in a fresh namespace,
and returns the namespace. Nothing else of the earlier chapter runs: no training, no plots.

The answers run as they are. An unsolved exercise still defines its function or class, whose body raises
``NotImplementedError`` when it is called (the student edition's stub), so the caller decides what an unsolved
answer means. Saving the earlier notebook is the learner's part: a cell edited but not saved is not read.

Taught in chapter 10.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import nbformat


class AnswersNotFoundError(FileNotFoundError):
    """The earlier chapter's notebook, or one of its cells, is not where the later chapter looks."""


def load_answers(notebook: str | Path, names: list[str], setup_cell: str = "c002") -> dict:
    """Execute the cell ``setup_cell`` of ``notebook`` and then every answer cell (nbgrader's ``solution`` cells) in
    the notebook's order, in one fresh namespace, and return that namespace, which must define ``names``. All the
    answers run because a later one may call an earlier one (an update calls its line search); an answer cell that
    fails (one that reads the earlier chapter's variables) defines nothing, and only a missing name is an error."""
    path = Path(notebook)
    if not path.is_file():
        raise AnswersNotFoundError(f"{path} is not here: keep the earlier chapter's notebook, saved, beside this one")
    cells = nbformat.read(path, as_version=4).cells
    setup = [cell for cell in cells if cell.get("id") == setup_cell]
    if not setup:
        raise AnswersNotFoundError(f"{path.name} has no cell {setup_cell}: is it this book's chapter?")
    namespace: dict = {"__name__": f"answers_of_{path.stem}"}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(setup[0].source, f"{path.name}:{setup_cell}", "exec"), namespace)
        for cell in cells:
            grading = cell.metadata.get("nbgrader", {})
            if cell.cell_type == "code" and grading.get("solution"):
                try:
                    exec(compile(cell.source, f"{path.name}:{grading['grade_id']}", "exec"), namespace)
                except Exception:  # noqa: BLE001 - a failing answer defines nothing; a missing name says so below
                    pass
    missing = [name for name in names if name not in namespace]
    if missing:
        raise AnswersNotFoundError(f"{path.name} defines no {', '.join(missing)}: is it this book's chapter?")
    return namespace
