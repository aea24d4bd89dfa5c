"""The self-learner's edition (issue 30): ``python -m vdtutorial notebooks DEST --student`` writes the
exercises as ``classroom release`` makes them, and the solutions apart, in ``DEST/solutions``."""

import json

import nbformat
import numpy as np
import pytest

pytest.importorskip("nbgrader", reason="nbgrader is the classroom extra (Colab's CI leg goes without it)")

from vdtutorial.course import classroom
from vdtutorial.__main__ import main
from vdtutorial.course.chapters import EditedFilesError, shipped_files
from vdtutorial.settings import BOOK_RECORD, shipped_dir

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only


def _sources(path):
    return [(c.cell_type, c.source) for c in nbformat.read(path, as_version=4).cells]


def test_student_edition_with_its_solutions_apart(tmp_path, capsys):
    dest = tmp_path / "learner"
    main(["notebooks", str(dest), "--student"])
    said = capsys.readouterr().out
    teacher = classroom.chapters()
    assert "student edition of" in said and str(dest / "solutions") in said
    classroom.release(tmp_path / "release")
    for name, path in teacher.items():
        student = dest / "notebooks" / f"{name}.ipynb"
        assert _sources(student) == _sources(tmp_path / "release" / f"{name}.ipynb"), name
        assert (dest / "solutions" / f"{name}.ipynb").read_bytes() == path.read_bytes(), name
        text = student.read_text()
        solved = path.read_text().count("### BEGIN SOLUTION")
        assert "BEGIN SOLUTION" not in text and text.count("raise NotImplementedError()") == solved, name
    data = [p for p in shipped_files() if p.parts[0] == "data"]
    assert all((dest / p).read_bytes() == (shipped_dir() / p).read_bytes() for p in data[:: max(1, len(data) // 20)])
    recorded = json.loads((dest / BOOK_RECORD).read_text())["files"]
    assert {f"solutions/{name}.ipynb" for name in teacher} <= set(recorded)


def test_student_edition_keeps_the_learners_answers(tmp_path):
    from vdtutorial.course.chapters import write_notebooks

    book = write_notebooks(tmp_path, student=True)
    assert book.chapters == book.solutions == len(classroom.chapters())
    assert book.appendices == len(list((shipped_dir() / "notebooks").glob("A[0-9]_*.ipynb"))) >= 3
    write_notebooks(tmp_path, student=True)  # untouched: written again without a word
    answer = tmp_path / "notebooks" / "01_environment.ipynb"
    answer.write_text(answer.read_text().replace("raise NotImplementedError()", "return 0.0", 1))
    with pytest.raises(EditedFilesError, match="01_environment.ipynb"):
        write_notebooks(tmp_path, student=True)
    assert "return 0.0" in answer.read_text()


def test_06b_two_bugs_are_the_librarys_whatever_the_learners_update():
    """06b's "two bugs" cell runs each bug in the library's update, so a learner whose own update already has a sign
    error sees the curves its answer key describes: the sign error falls below the library's run, the reversed KL
    runs as the library's."""
    nb = nbformat.read(classroom.chapters()["06b_trpo_assembled"], as_version=4)
    answer = {
        c.metadata["nbgrader"]["grade_id"]: c.source for c in nb.cells if c.metadata.get("nbgrader", {}).get("solution")
    }
    first = next(c.source for c in nb.cells if "from unittest import mock" in c.source)
    runs = next(c.source for c in nb.cells if c.source.startswith("def pendulum_trpo("))
    bugs = next(c.source for c in nb.cells if "bug_returns = {}" in c.source)
    right = "return (ratio * advantages).mean(), mean_kl(old, dist)"
    assert answer["ch06_trpo_update"].count(right) == 1
    learner = answer["ch06_trpo_update"].replace(right, "return -(ratio * advantages).mean(), mean_kl(old, dist)")
    names: dict = {}
    for source in (first, runs, answer["ch06_line_search"], learner):
        exec(source, names)
    library = names["pendulum_trpo"](seed=0)
    rows = library.run(8 * names["PENDULUM_CONFIG"].steps_per_iter, progress=False)
    library.close()
    names.update(
        mean_return=np.array([r["mean_return"] for r in rows]),
        kls=np.array([r["mean_kl"] for r in rows]),
        env_steps=np.array([r["env_steps"] for r in rows]),
    )
    exec(bugs, names)
    returns = names["bug_returns"]
    np.testing.assert_allclose(returns["KL reversed"], names["mean_return"], rtol=1e-3)
    assert returns["sign error"][-1] < min(names["mean_return"][0], returns["sign error"][0]) - 50, returns
