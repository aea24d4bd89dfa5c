"""The trusted checks' protocol (issue 43): what may cross from the student's kernel to the grader, and how every
exercise is wired to its check. Each chapter's checks are tested against the teacher's solutions and wrong answers
in tests/test_checks_chNN.py."""

import os
import re

import nbformat
import numpy as np
import pytest
import torch

from vdtutorial.course import checks, classroom

HIDDEN = re.compile(r"### BEGIN HIDDEN TESTS\n(.*?)### END HIDDEN TESTS", re.S)


def exercises():
    found = []
    for path in classroom.chapters().values():
        for cell in nbformat.read(path, as_version=4).cells:
            grade_id = cell.metadata.get("nbgrader", {}).get("grade_id", "")
            if grade_id.endswith("_tests"):
                found.append((grade_id.removesuffix("_tests"), cell.source))
    return found


def test_every_exercise_has_a_check_and_its_hidden_tests_are_only_the_call():
    found = exercises()
    assert len(found) >= 20
    assert {name for name, _ in found} == set(checks.every_check())
    for name, source in found:
        assert HIDDEN.search(source).group(1) == (
            f'from vdtutorial.course.checks import run_check\nrun_check("{name}", globals())\n'
        ), name


def test_the_checks_follow_the_chapters_order():
    assert list(checks.every_check()) == [name for name, _ in exercises()]


class Anything:
    """Equal to everything: the comparison such an object would win never happens, since it cannot be sent."""

    def __eq__(self, other):
        return True

    def __bool__(self):
        return True


class Liar(torch.Tensor):
    def __eq__(self, other):
        return True


def test_only_plain_numbers_cross_from_the_kernel():
    with pytest.raises(TypeError):
        checks.plain({"answer": Anything()})
    with pytest.raises(TypeError):
        checks.plain({"answer": [1.0, Anything()]})
    sent = checks.plain({"a": torch.zeros(3).as_subclass(Liar), "b": {"c": [1, 2]}, "d": 2.5})
    assert type(sent["a"]) is np.ndarray and sent["a"].tolist() == [0.0, 0.0, 0.0]
    assert sent["b/c"].tolist() == [1, 2] and checks.nested(sent)["b"]["c"].tolist() == [1, 2]


def test_the_grader_reads_only_plain_files(tmp_path):
    checks.save(tmp_path / "good.npz", {"x": np.arange(3)})
    assert checks.load(tmp_path / "good.npz")["x"].tolist() == [0, 1, 2]
    np.savez(tmp_path / "pickled.npz", x=np.array([Anything()], dtype=object))
    with pytest.raises(ValueError):
        checks.load(tmp_path / "pickled.npz")
    os.symlink(tmp_path / "good.npz", tmp_path / "link.npz")
    with pytest.raises(ValueError):
        checks.load(tmp_path / "link.npz")


def test_a_missing_or_raising_answer_fails_in_words():
    item = checks.check("ch02_step_towards")
    inputs = checks.plain(item.inputs(np.random.default_rng(1)))
    assert "no answer" in checks.judge(item, inputs, None)[0]
    assert checks.judge(item, inputs, {checks.RAISED: np.array("ZeroDivisionError")}) == [
        "your code raised ZeroDivisionError on the hidden check's inputs"
    ]
    failed = checks.judge(item, inputs, {"nonsense": np.zeros(2)})
    assert len(failed) == 1 and "could not be checked" in failed[0]


def test_answers_from_another_grading_run_fail():
    """The inputs are drawn afresh for each submission: outputs right for one draw are wrong for another."""
    from vdtutorial.expert import step_towards

    item = checks.check("ch02_step_towards")
    namespace = {"my_step": step_towards}
    first, second = (checks.plain(item.inputs(np.random.default_rng(seed))) for seed in (1, 2))
    replayed = checks._probe(item, namespace, first)
    assert checks.judge(item, first, replayed) == []
    assert checks.judge(item, second, replayed) != []


def test_a_notebook_checks_itself_outside_grading(monkeypatch):
    from vdtutorial.expert import step_towards

    monkeypatch.delenv(checks.EXCHANGE_ENV, raising=False)
    checks.run_check("ch02_step_towards", {"my_step": step_towards})
    with pytest.raises(AssertionError, match="ch02_step_towards: "):
        checks.run_check("ch02_step_towards", {"my_step": lambda goal, j: np.zeros(6)})


def test_under_grading_the_kernel_only_writes_outputs(tmp_path, monkeypatch):
    item = checks.check("ch02_step_towards")
    inputs = checks.plain(item.inputs(np.random.default_rng(4)))
    checks.save(checks.inputs_path(tmp_path, item.exercise), inputs)
    monkeypatch.setenv(checks.EXCHANGE_ENV, str(tmp_path))
    checks.run_check(item.exercise, {"my_step": lambda goal, j: np.zeros(6)})  # wrong, and no error here
    outputs = checks.load(checks.outputs_path(tmp_path, item.exercise))
    assert checks.judge(item, inputs, outputs) != []
