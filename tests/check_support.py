"""What the tests of the trusted checks (tests/test_checks_chNN.py) share: the teacher's answers read from a chapter
notebook, the edits that turn one into a student's mistake or an unsolved stub, the notebook's namespace the answer
cells run in, and the grader's steps with the rule every failure message keeps (no number given away).

The test files import it as they import conftest's helpers (``from check_support import ...``): pytest puts tests/,
which has no ``__init__.py``, on ``sys.path``."""

import re
from pathlib import Path

import nbformat
import numpy as np

from vdtutorial.course import checks

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
#: A solution block of an answer cell, markers included (each answer cell has one).
SOLUTION = re.compile(r"### BEGIN SOLUTION.*?### END SOLUTION", re.S)
#: The whole feedback on an unsolved stub: the check reports the stub, it does not crash on it.
UNSOLVED = ["your code raised NotImplementedError on the hidden check's inputs"]


def notebook(stem: str) -> nbformat.NotebookNode:
    """The chapter notebook ``notebooks/<stem>.ipynb`` as the repository ships it: the teacher's edition, whose answer
    cells hold the solutions the checks must accept."""
    return nbformat.read(NOTEBOOKS / f"{stem}.ipynb", as_version=4)


def answers(stem: str) -> dict[str, str]:
    """{grade_id: source} of the answer cells (nbgrader ``solution`` cells) of the notebook ``stem``, in the notebook's
    order: the teacher's solutions, and the order the chapter's CHECKS follow."""
    return {
        cell.metadata["nbgrader"]["grade_id"]: cell.source
        for cell in notebook(stem).cells
        if cell.metadata.get("nbgrader", {}).get("solution")
    }


def stub(source: str) -> str:
    """``source`` with its solution block replaced by ``raise NotImplementedError()``, as the student edition ships the
    cell: the unsolved answer, which a check must fail with UNSOLVED."""
    return SOLUTION.sub("raise NotImplementedError()", source)


def changed(source: str, old: str, new: str) -> str:
    """``source`` with ``old`` replaced by ``new``: a student's plausible mistake. ``old`` must be in ``source``, so
    that an edit which no longer matches the teacher's solution fails loudly instead of testing the right answer as a
    wrong one."""
    assert old in source, old
    return source.replace(old, new)


def executed(context: dict, *sources: str) -> dict:
    """The namespace the chapter's kernel gives an answer cell: a copy of ``context`` (the names the answer cells use
    from the chapter's first cells), then each of ``sources`` run in it in order (cells that a later answer calls
    first)."""
    namespace = dict(context)
    for source in sources:
        exec(source, namespace)
    return namespace


def failures(exercise: str, namespace: dict, seed: int) -> list[str]:
    """The grader's verdict on ``exercise``, in its steps: inputs from a generator seeded ``seed``, made plain; the
    probe run on the answer in ``namespace``; the messages of what failed. Asserts that no message holds a decimal
    number: the feedback must not give the hidden expected values away."""
    item = checks.check(exercise)
    inputs = checks.plain(item.inputs(np.random.default_rng(seed)))
    found = checks.judge(item, inputs, checks._probe(item, namespace, inputs))
    assert all(re.search(r"\d\.\d", message) is None for message in found), found
    return found


def assert_passes(exercise: str, context: dict, source: str, seeds) -> None:
    """The answer ``source`` (run after ``context``) passes ``exercise``'s check on every seed of ``seeds``."""
    namespace = executed(context, source)
    for seed in seeds:
        assert failures(exercise, namespace, seed) == [], (exercise, seed)


def assert_mistake_fails(exercise: str, context: dict, source: str, mistakes: dict, mistake: str) -> None:
    """``source`` with the named edit of ``mistakes`` (or "stub": the unsolved cell) fails ``exercise``'s check; the
    stub with the words for an unsolved exercise."""
    source = stub(source) if mistake == "stub" else changed(source, *mistakes[mistake])
    found = failures(exercise, executed(context, source), seed=1)  # no message gives a number away
    assert found, (exercise, mistake)
    if mistake == "stub":
        assert found == UNSOLVED
