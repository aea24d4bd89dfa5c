"""A learner's answers read from an earlier chapter's notebook (chapter 10's capstone)."""

import nbformat
import pytest
import torch

from vdtutorial.course.your_code import AnswersNotFoundError, load_answers
from vdtutorial.settings import shipped_dir
from vdtutorial.vd import LinearSVDO


def _notebook(path, cells):
    notebook = nbformat.v4.new_notebook()
    for cell_id, source, grade_id in cells:
        cell = nbformat.v4.new_code_cell(source)
        cell.id = cell_id
        if grade_id:
            cell.metadata["nbgrader"] = {"grade_id": grade_id, "solution": True, "grade": False}
        notebook.cells.append(cell)
    nbformat.write(notebook, path)
    return path


def test_the_teachers_layer_of_chapter_04_is_the_librarys():
    layer = load_answers(shipped_dir() / "notebooks" / "04_sparse_variational_dropout.ipynb", ["MyLinearSVDO"])[
        "MyLinearSVDO"
    ]
    torch.manual_seed(0)
    mine, ref = layer(4, 3), LinearSVDO(4, 3)
    with torch.no_grad():
        for name in ("weight", "bias", "log_sigma2"):
            getattr(mine, name).copy_(getattr(ref, name))
    torch.testing.assert_close(mine.kl(), ref.kl())
    torch.testing.assert_close(mine.eval()(torch.ones(2, 4)), ref.eval()(torch.ones(2, 4)))


def test_answers_run_in_order_after_the_setup_cell_and_a_failing_one_defines_nothing(tmp_path, capsys):
    path = _notebook(
        tmp_path / "ch.ipynb",
        [
            ("c002", "SCALE = 3\nprint('setup')", None),
            ("other", "raise RuntimeError('not run: not an answer')", None),
            ("a1", "def double(x):\n    return 2 * x", "ex_double"),
            ("a2", "result = chapter_variable + 1", "ex_broken"),  # reads a variable of the chapter: fails
            ("a3", "def scaled(x):\n    return SCALE * double(x)", "ex_scaled"),
            ("a4", "def unsolved():\n    raise NotImplementedError()", "ex_unsolved"),
        ],
    )
    answers = load_answers(path, ["scaled", "unsolved"])
    assert answers["scaled"](2) == 12 and "result" not in answers
    with pytest.raises(NotImplementedError):
        answers["unsolved"]()
    assert capsys.readouterr().out == "", "the setup cell's printing is not the later chapter's"


def test_a_missing_notebook_cell_or_name_is_a_clear_error(tmp_path):
    with pytest.raises(AnswersNotFoundError, match="beside this one"):
        load_answers(tmp_path / "04_missing.ipynb", ["MyLinearSVDO"])
    path = _notebook(tmp_path / "ch.ipynb", [("first", "x = 1", None), ("a1", "def f():\n    pass", "ex_f")])
    with pytest.raises(AnswersNotFoundError, match="no cell c002"):
        load_answers(path, ["f"])
    assert load_answers(path, ["f"], setup_cell="first")["x"] == 1
    with pytest.raises(AnswersNotFoundError, match="defines no g"):
        load_answers(path, ["f", "g"], setup_cell="first")
