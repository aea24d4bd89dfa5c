"""The classroom edition (issue 10): exercises, the student edition and autograding, all through nbgrader.

The chapter tests execute notebooks (each chapter three times: unsolved, teacher's, one wrong answer), so
they are parametrised per chapter and spread over the xdist workers; the release is made once per worker.
"""

import csv
import errno
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import nbformat
import pytest

pytest.importorskip("nbgrader", reason="nbgrader is the classroom extra (Colab's CI leg goes without it)")

from vdtutorial.course import classroom, sandbox
from vdtutorial.__main__ import main

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

CHAPTERS = [name for name in classroom.chapters() if name != "00_start_here"]
SOLUTION = re.compile(r"### BEGIN SOLUTION\n(.*?)### END SOLUTION", re.S)
HIDDEN = re.compile(r"### BEGIN HIDDEN TESTS\n(.*?)### END HIDDEN TESTS", re.S)
# One deliberately wrong answer per chapter: (exercise, text of the teacher's solution, the wrong version).
WRONG = {
    "01_environment": ("ch01_reward_eq11", '"-d_t": -distance,', '"-d_t": distance,'),
    "02_ik_expert": ("ch02_step_towards", "diff * min(1.0, MAX_DELTA / largest)", "diff * MAX_DELTA / largest"),
    "03_demonstrations": ("ch03_noisy_rollout", "labels.append(label)", "labels.append(-label)"),
    "04_sparse_variational_dropout": (
        "ch04_svdo_layer",
        "- 0.5 * F.softplus(-self.log_alpha)",
        "+ 0.5 * F.softplus(-self.log_alpha)",
    ),
    "05_pretraining": (
        "ch05_elbo_step",
        "nll + beta * model_kl(policy.mu) / n_train",
        "nll - beta * model_kl(policy.mu) / n_train",
    ),
    "06a_trpo_pieces": ("ch06_gae", "alive = 1.0 - dones[t]", "alive = 1.0"),
    "06b_trpo_assembled": ("ch06_line_search", "if kl <= config.max_kl and gain > 0:", "if kl <= config.max_kl:"),
    "07_finetuning": ("ch07_prune", "keep = log_alpha <= threshold", "keep = log_alpha > threshold"),
    "08_grasping": ("ch08_grasp_success", "min(1.0, abs(approach[2]))", "min(1.0, approach[2])"),
    "09_beyond_the_paper": ("ch09_dart_noise", "errors.T @ errors / len(errors)", "errors.T @ errors"),
    "10_what_reproduced": (
        "ch10_welch_verdict",
        "stats.t.ppf((1 + confidence) / 2, dof)",
        "stats.t.ppf(confidence, dof)",
    ),
    "11_your_method": (
        "ch11_l1_penalty",
        "total = sum(w.abs().sum() for w in weights)",
        "total = sum((w**2).sum() for w in weights)",
    ),
}


def cells(path):
    return nbformat.read(path, as_version=4).cells


def nbgrader(cell):
    return cell.metadata.get("nbgrader", {})


def test_every_chapter_has_graded_exercises_with_visible_and_hidden_tests():
    """Every chapter (both notebooks of a chapter in parts, such as 06a and 06b) has at least two exercises."""
    total, per_chapter = 0, {}
    for name in CHAPTERS:
        tests = [c for c in cells(classroom.chapters()[name]) if nbgrader(c).get("grade")]
        answers = [c for c in cells(classroom.chapters()[name]) if nbgrader(c).get("solution")]
        assert tests and len(answers) == len(tests), name
        per_chapter[name[:2]] = per_chapter.get(name[:2], 0) + len(tests)
        for cell in tests:
            visible = HIDDEN.sub("", cell.source)
            assert "assert" in visible and HIDDEN.search(cell.source), nbgrader(cell)["grade_id"]
            assert nbgrader(cell)["points"] > 0 and nbgrader(cell)["locked"]
        for cell in answers:
            assert SOLUTION.search(cell.source), nbgrader(cell)["grade_id"]
        total += len(tests)
    assert min(per_chapter.values()) >= 2 and total >= 20, per_chapter


@pytest.fixture(scope="session")
def released(tmp_path_factory):
    out = tmp_path_factory.mktemp("student")
    classroom.release(out)
    return out


def test_release_has_no_solution_and_no_hidden_test(released):
    for name, path in classroom.chapters().items():
        teacher = "\n".join(c.source for c in cells(path))
        student = cells(released / f"{name}.ipynb")
        text = "\n".join(c.source for c in student)
        public = SOLUTION.sub("", HIDDEN.sub("", teacher))  # lines also written elsewhere are no secret
        secret = [
            line.strip()
            for block in SOLUTION.findall(teacher) + HIDDEN.findall(teacher)
            for line in block.splitlines()
            if len(line.strip()) > 12 and line.strip() not in public
        ]
        assert len(secret) >= 3 * len(SOLUTION.findall(teacher)), name
        leaked = [line for line in secret if line in text]
        assert not leaked, (name, leaked[:3])
        assert "BEGIN SOLUTION" not in text and "HIDDEN TESTS" not in text
        assert text.count("raise NotImplementedError()") == len(SOLUTION.findall(teacher))
        assert all(not c.get("outputs") for c in student if c.cell_type == "code")


@pytest.mark.parametrize("chapter", CHAPTERS)
def test_grading_a_chapter(chapter, released, tmp_path):
    """Unsolved: runs to the end, only exercise cells fail, 0 points. Teacher: full points. One wrong
    answer: exactly that exercise's points are lost."""
    exercise, right, wrong = WRONG[chapter]
    source = classroom.chapters()[chapter]
    teacher_text = source.read_text()
    assert teacher_text.count(json.dumps(right)[1:-1]) == 1, "the mutation must hit the solution exactly once"
    for student, text in (
        ("unsolved", (released / f"{chapter}.ipynb").read_text()),
        ("teacher", teacher_text),
        ("wrong", teacher_text.replace(json.dumps(right)[1:-1], json.dumps(wrong)[1:-1])),
    ):
        (tmp_path / "in" / student).mkdir(parents=True)
        (tmp_path / "in" / student / f"{chapter}.ipynb").write_text(text)
    scores = classroom.grade(sorted((tmp_path / "in").iterdir()), tmp_path / "course")

    points = {(s.student, s.exercise): (s.score, s.max_score) for s in scores}
    tests = {s.exercise for s in scores}
    assert tests
    assert all(points["unsolved", t][0] == 0 for t in tests)
    assert all(points["teacher", t][0] == points["teacher", t][1] > 0 for t in tests), points
    lost = {t for t in tests if points["wrong", t][0] < points["wrong", t][1]}
    assert lost == {f"{exercise}_tests"}, lost
    assert points["wrong", f"{exercise}_tests"][0] == 0

    def errors(student):
        ran = cells(tmp_path / "course" / "autograded" / student / classroom.ASSIGNMENT / f"{chapter}.ipynb")
        found = {c.id: o for c in ran if c.cell_type == "code" for o in c.outputs if o.output_type == "error"}
        return found, {c.id for c in ran if nbgrader(c).get("grade") or nbgrader(c).get("solution")}

    # The grading kernel has the pieces the exercises rebuild as stubs (course/stubs.py): a chapter cell that runs
    # one fails there, the teacher's edition too, and so may a cell that uses what such a cell would have made.
    failed, exercise_cells = errors("unsolved")
    stubbed, _ = errors("teacher")
    assert failed and set(failed) - set(stubbed) <= exercise_cells, set(failed) - set(stubbed) - exercise_cells
    assert all(
        "is stubbed in grading" in o.evalue or o.ename == "NameError"
        for cell, o in stubbed.items()
        if cell not in exercise_cells
    ), {cell: o.evalue for cell, o in stubbed.items()}
    assert (tmp_path / "course" / "gradebook.db").is_file() and (tmp_path / "course" / "grades.csv").is_file()


def run_cli(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    return exit_info.value.code, err[-1]


def test_grade_refuses_bad_input_with_one_line(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "bob").mkdir()
    (tmp_path / "bob" / "01_environment.ipynb").write_text("not json")
    (tmp_path / "bob" / "99_nothing.ipynb").write_text(classroom.chapters()["00_start_here"].read_text())
    (tmp_path / "eve").mkdir()
    (tmp_path / "eve" / "01_environment.ipynb").write_text(classroom.chapters()["00_start_here"].read_text())
    cases = {
        str(tmp_path / "notes.txt"): "is not a notebook",
        str(tmp_path / "missing.ipynb"): "no such file",
        str(tmp_path / "bob" / "01_environment.ipynb"): "is not a Jupyter notebook",
        str(tmp_path / "bob" / "99_nothing.ipynb"): "there is no chapter '99_nothing'",
        str(tmp_path / "eve" / "01_environment.ipynb"): "not from this edition",
    }
    for path, message in cases.items():
        code, last = run_cli(["classroom", "grade", path, "--out", str(tmp_path / "course")], capsys)
        assert code == 2 and last.startswith("error: ") and message in last, (path, last)
    assert not (tmp_path / "course" / "gradebook.db").exists(), "nothing is graded when the input is bad"


def _gradebook_scores(course):
    """(student, chapter, grade cell) -> score, as nbgrader's own gradebook holds them."""
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{course / 'gradebook.db'}") as gb:
        return {
            (sub.student.id, nb.name, g.name): g.score
            for sub in gb.assignment_submissions(classroom.ASSIGNMENT)
            for nb in sub.notebooks
            for g in nb.grades
            if g.score is not None
        }


@pytest.mark.parametrize("backend", ["local", "ray"])
def test_a_class_is_graded_in_parallel_into_one_consistent_gradebook(backend, released, tmp_path):
    """Four submissions of chapter 01, two at a time (worker processes, or a private local Ray): the same points as
    one at a time would give (the teacher's full, the released edition's 0, each twice), every one of them in the
    gradebook as in grades.csv, and a line per submission as it is graded."""
    if backend == "ray":
        pytest.importorskip("ray")
    chapter = "01_environment"
    for student, source in (
        ("t1", classroom.chapters()[chapter]),
        ("t2", classroom.chapters()[chapter]),
        ("u1", released / f"{chapter}.ipynb"),
        ("u2", released / f"{chapter}.ipynb"),
    ):
        (tmp_path / "in" / student).mkdir(parents=True)
        (tmp_path / "in" / student / f"{chapter}.ipynb").write_bytes(source.read_bytes())
    lines = []
    scores = classroom.grade(
        sorted((tmp_path / "in").iterdir()), tmp_path / "course", workers=2, backend=backend, log=lines.append
    )
    totals = {st: sum(s.score for s in scores if s.student == st) for st in ("t1", "t2", "u1", "u2")}
    possible = sum(s.max_score for s in scores if s.student == "t1")
    assert possible > 0 and totals == {"t1": possible, "t2": possible, "u1": 0, "u2": 0}
    assert _gradebook_scores(tmp_path / "course") == {(s.student, s.chapter, s.exercise): s.score for s in scores}
    passed = {st: sum(s.score > 0 for s in scores if s.student == st) for st in totals}
    assert sorted(line.split("] ", 1)[1] for line in lines) == sorted(
        f"{st} {chapter}: {passed[st]} of 3 exercises pass their checks" for st in totals
    )
    for st in totals:
        assert (tmp_path / "course" / "autograded" / st / classroom.ASSIGNMENT / f"{chapter}.ipynb").is_file()


def test_an_unreachable_ray_address_fails_grading_within_30_s_in_one_line(released, tmp_path):
    pytest.importorskip("ray")
    (tmp_path / "in" / "ann").mkdir(parents=True)
    (tmp_path / "in" / "ann" / "01_environment.ipynb").write_bytes((released / "01_environment.ipynb").read_bytes())
    start = time.monotonic()
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "vdtutorial",
            "classroom",
            "grade",
            str(tmp_path / "in" / "ann"),
            "--out",
            str(tmp_path / "course"),
            "--address",
            "127.0.0.1:1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert time.monotonic() - start < 30
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1].startswith("error: no Ray cluster answers at 127.0.0.1:1")


#: Chapter 04 (Exercises 4.2 and 4.3) as two hostile students hand it in: the teacher's solutions, with one more
#: answer cell's code in front (issue 43's attacks, tried on chapter 04's exercises).
HOSTILE = {
    # the library's own layer, under the student's name: 4.2 scores 0, 4.3 (the teacher's) keeps its points
    "copier": ("ch04_svdo_layer", "from vdtutorial.vd import LinearSVDO as MyLinearSVDO\n", {"ch04_svdo_layer_tests"}),
    # the comparison disarmed for every later test: the whole notebook scores 0
    "patcher": ("ch04_svdo_layer", "import torch\ntorch.testing.assert_close = lambda *args, **kwargs: None\n", None),
}


def test_an_answer_that_calls_the_reference_or_patches_the_tests_is_refused(tmp_path):
    """Refused before it runs, with the reason in the teacher's table, grades.csv and the gradebook's comment."""
    teacher = classroom.chapters()["04_sparse_variational_dropout"]
    for student, (exercise, code, _) in HOSTILE.items():
        nb = nbformat.read(teacher, as_version=4)
        answer = next(c for c in nb.cells if nbgrader(c).get("grade_id") == exercise and nbgrader(c).get("solution"))
        answer.source = code + answer.source
        (tmp_path / "in" / student).mkdir(parents=True)
        nbformat.write(nb, tmp_path / "in" / student / teacher.name)
    lines = []
    scores = classroom.grade(sorted((tmp_path / "in").iterdir()), tmp_path / "course", workers=2, log=lines.append)
    tests = {s.exercise for s in scores}
    for student, (exercise, _, lost) in HOSTILE.items():
        lost = tests if lost is None else lost
        got = {s.exercise: s for s in scores if s.student == student}
        assert {e for e, s in got.items() if s.score == 0} == lost, student
        assert all(got[e].score == got[e].max_score for e in tests - lost), student
        assert all(got[e].refused.startswith(exercise + " line ") for e in lost), student
    assert any(line.startswith("refused patcher") for line in lines), lines
    printed = classroom.table(scores)
    assert "0!" in printed and "uses the library's LinearSVDO" in printed and "changes torch.testing" in printed
    with open(tmp_path / "course" / "grades.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["student"] for r in rows if r["refused"]} == {"copier", "patcher"}
    from nbgrader.api import Gradebook

    with Gradebook(f"sqlite:///{tmp_path / 'course' / 'gradebook.db'}") as gb:
        comment = gb.find_comment("ch04_svdo_layer", teacher.stem, classroom.ASSIGNMENT, "copier")
        assert comment.manual_comment.startswith("refused by the grader: ch04_svdo_layer line 1")


#: A layer that is not sparse VD at all (log alpha 0, no KL, a plain linear map): right shapes, wrong numbers.
_FAKE_LAYER = """
class MyLinearSVDO(nn.Module):
    def __init__(self, n_in, n_out):
        super().__init__()
        bound = 1 / math.sqrt(n_in)
        self.weight = nn.Parameter(torch.empty(n_out, n_in).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(n_out).uniform_(-bound, bound))
        self.log_sigma2 = nn.Parameter(torch.full((n_out, n_in), LOG_SIGMA2_INIT))
    log_alpha = property(lambda self: torch.zeros_like(self.weight))
    def keep_mask(self):
        return torch.ones_like(self.weight, dtype=torch.bool)
    def kl(self):
        return 0 * self.weight.sum()
    def forward(self, x):
        return F.linear(x, self.weight, self.bias)
"""
#: Issue 43's classes of hostile submission, each as chapter 04's answer 4.2 (answer 4.3 stays the teacher's, solved).
#: Graded with the static check off: the points must come out right from the trusted checks alone.
ATTACKS = {
    # the comparisons and the library's reference patched, so that 4.2's visible tests pass in the kernel
    "patcher": "import numpy as np\nimport vdtutorial.vd\n"
    "torch.testing.assert_close = lambda *args, **kwargs: None\n"
    "np.testing.assert_allclose = lambda *args, **kwargs: None\n"
    "torch.equal = lambda *args, **kwargs: True\ntorch.all = lambda *args, **kwargs: torch.tensor(True)\n"
    "math.isclose = lambda *args, **kwargs: True\nimport builtins\nbuiltins.all = lambda *args: True\n"
    "vdtutorial.vd.kl_approx = lambda log_alpha: 0 * log_alpha\n"
    "import vdtutorial.course.checks as _checks\n_checks.judge = lambda *args, **kwargs: []\n" + _FAKE_LAYER,
    # errors no longer displayed (nbgrader PR 1324's attack), so that failing tests record none
    "silencer": "get_ipython().showtraceback = lambda *args, **kwargs: None\n" + _FAKE_LAYER,
    # the kernel exits in the answer: nothing after it runs
    "quitter": "import os\nos._exit(0)\n",
    # objects that compare equal to anything: a tensor subclass and an object with __eq__ and __array__
    "flatterer": "class _Yes(torch.Tensor):\n    def __eq__(self, other):\n"
    "        return torch.ones_like(other, dtype=torch.bool)\n"
    "class _Always:\n    def __eq__(self, other):\n        return True\n"
    "    def __array__(self, *args, **kwargs):\n        return np.zeros(1)\n"
    + _FAKE_LAYER
    + "MyLinearSVDO.log_alpha = property(lambda self: torch.zeros_like(self.weight).as_subclass(_Yes))\n"
    "MyLinearSVDO.kl = lambda self: _Always()\n",
    # files the grader reads: forged outputs of both checks, a link, and the gradebooks it can find
    "forger": "import glob\nimport os\nimport numpy as np\n"
    "_exchange = os.environ.get('VDTUTORIAL_CHECKS', '.')\n"
    "np.savez(os.path.join(_exchange, 'ch04_svdo_layer.outputs.npz'), log_alpha=np.zeros(3))\n"
    "os.symlink(os.path.join(_exchange, 'ch04_svdo_layer.inputs.npz'), os.path.join(_exchange, 'x.npz'))\n"
    "for _db in glob.glob('/tmp/*/course/gradebook.db'):\n"
    "    try:\n        open(_db, 'wb').close()\n    except OSError:\n        pass\n" + _FAKE_LAYER,
}


def test_hostile_submissions_score_only_what_they_solved(tmp_path):
    """Issue 43's Done-when: each class of hostile submission scores 0 on the exercise it did not solve (4.2) and
    its points on the one it did (4.3, the teacher's answer), except the quitter, whose kernel never reaches 4.3."""
    teacher = classroom.chapters()["04_sparse_variational_dropout"]
    for student, code in ATTACKS.items():
        nb = nbformat.read(teacher, as_version=4)
        answer = next(
            c for c in nb.cells if nbgrader(c).get("grade_id") == "ch04_svdo_layer" and nbgrader(c).get("solution")
        )
        answer.source = code
        (tmp_path / "in" / student).mkdir(parents=True)
        nbformat.write(nb, tmp_path / "in" / student / teacher.name)
    scores = classroom.grade(sorted((tmp_path / "in").iterdir()), tmp_path / "course", workers=2, static_check=False)
    got = {(s.student, s.exercise): s.score for s in scores}
    for student in ATTACKS:
        assert got[student, "ch04_svdo_layer_tests"] == 0, student
        assert got[student, "ch04_compact_tests"] == (0 if student == "quitter" else 3), student
    ran = cells(tmp_path / "course" / "autograded" / "patcher" / classroom.ASSIGNMENT / teacher.name)
    tests = next(c for c in ran if nbgrader(c).get("grade_id") == "ch04_svdo_layer_tests")
    # the patched tests passed in the kernel, but for the library's pieces they call, which are stubs there
    errors = [o for o in tests.outputs if o.output_type == "error"]
    assert all("is stubbed in grading" in o.evalue for o in errors), [o.evalue for o in errors]
    failed = {s.student: s.failed for s in scores if s.exercise == "ch04_svdo_layer_tests"}
    assert any("kl()" in why for why in failed["patcher"]), failed["patcher"]


def test_feedback_names_what_failed_without_the_hidden_checks(tmp_path):
    """A wrong KL passes the visible tests of 4.2 when they are disarmed, and fails the hidden check: the student's
    page says which check failed, in words, with neither the check's code nor the reference's values."""
    teacher = classroom.chapters()["04_sparse_variational_dropout"]
    nb = nbformat.read(teacher, as_version=4)
    answer = next(
        c for c in nb.cells if nbgrader(c).get("grade_id") == "ch04_svdo_layer" and nbgrader(c).get("solution")
    )
    answer.source = "torch.testing.assert_close = lambda *args, **kwargs: None\n" + answer.source.replace(
        "- 0.5 * F.softplus(-self.log_alpha)", "- 0.4 * F.softplus(-self.log_alpha)"
    )
    tests = next(c for c in nb.cells if nbgrader(c).get("grade_id") == "ch04_svdo_layer_tests")
    (tmp_path / "in" / "erin").mkdir(parents=True)
    nbformat.write(nb, tmp_path / "in" / "erin" / teacher.name)
    scores = classroom.grade([tmp_path / "in" / "erin"], tmp_path / "course", static_check=False)
    assert {s.exercise: s.score for s in scores} == {
        "ch04_gaussian_dropout_tests": 2,
        "ch04_svdo_layer_tests": 0,
        "ch04_compact_tests": 3,
    }
    page = (tmp_path / "course" / "feedback" / "erin" / f"{teacher.stem}.md").read_text()
    assert "Points: 5 of 9." in page and "hidden check failed:" in page and "kl()" in page
    from vdtutorial.course.checks import ch04

    secret = [line.strip() for line in HIDDEN.search(tests.source).group(1).splitlines()]
    secret += [line.strip() for line in Path(ch04.__file__).read_text().splitlines() if len(line.strip()) > 15]
    assert not [line for line in secret if line and line in page]
    hidden_lines = [line for line in page.splitlines() if line.startswith("- hidden check failed")]
    assert hidden_lines and not any(re.search(r"\d\.\d", line) for line in hidden_lines), hidden_lines


def test_release_refuses_to_overwrite(released, capsys):
    code, last = run_cli(["classroom", "release", str(released)], capsys)
    assert code == 2 and "already holds" in last


def test_a_looping_cell_is_interrupted_and_the_rest_still_runs(tmp_path):
    """nbgrader's per-cell timeout: a submission that loops forever is cut off in that cell only."""
    nb = nbformat.read(classroom.chapters()["00_start_here"], as_version=4)
    nb.cells.insert(3, nbformat.v4.new_code_cell("while True:\n    pass"))
    (tmp_path / "mallory").mkdir()
    nbformat.write(nb, tmp_path / "mallory" / "00_start_here.ipynb")
    assert classroom.grade([tmp_path / "mallory"], tmp_path / "course", timeout=60) == []  # chapter 00 has no exercises
    ran = cells(tmp_path / "course" / "autograded" / "mallory" / classroom.ASSIGNMENT / "00_start_here.ipynb")
    code = [c for c in ran if c.cell_type == "code"]
    looping = next(c for c in code if c.source.startswith("while True"))
    assert any(o.output_type == "error" for o in looping.outputs)
    after = code[code.index(looping) + 1 :]
    # each ran without an error (what they print may differ: the sandbox shows the kernel no teacher's notebooks)
    assert after and all(c.execution_count is not None for c in after), "the cells after the loop still ran"
    assert not any(o.output_type == "error" for c in after for o in c.outputs)


def _attacked(tmp_path, student, attacks):
    """Chapter 01 solved by the teacher, with code put in front of some exercises' answers ({grade_id: code})."""
    nb = nbformat.read(classroom.chapters()["01_environment"], as_version=4)
    for cell in nb.cells:
        if nbgrader(cell).get("grade_id") in attacks and nbgrader(cell).get("solution"):
            cell.source = attacks[nbgrader(cell)["grade_id"]] + "\n" + cell.source
    (tmp_path / "in" / student).mkdir(parents=True)
    nbformat.write(nb, tmp_path / "in" / student / "01_environment.ipynb")
    return tmp_path / "in" / student


def _lost(scores, student):
    return {s.exercise for s in scores if s.student == student and s.score < s.max_score}


def test_a_submission_past_the_memory_cap_loses_only_that_exercise(tmp_path):
    """6 GB of zeroed bytes cost nothing until touched, so without the cap the allocation would succeed here;
    under a 2 GB cap it raises MemoryError in that answer. Graded by the command line in its own process (as
    a teacher runs it, with Python's default warning filters), whose output is the points table and the real
    errors only: no SQLAlchemy warning, no kernel transport warning."""
    hog = _attacked(tmp_path, "hog", {"ch01_reward_eq11": "_hog = bytearray(6 << 30)"})
    nb = nbformat.read(classroom.chapters()["01_environment"], as_version=4)
    # the kernel dies, by a way the static check lets through (os._exit would be refused before it ran): nbgrader
    # gives up on that notebook, and only on it
    nb.cells.insert(
        3, nbformat.v4.new_code_cell("import os\nimport subprocess\nsubprocess.run(['kill', '-9', str(os.getpid())])")
    )
    (tmp_path / "in" / "crash").mkdir()
    nbformat.write(nb, tmp_path / "in" / "crash" / "01_environment.ipynb")
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "vdtutorial",
            "classroom",
            "grade",
            str(hog),
            str(tmp_path / "in" / "crash"),
            "--out",
            str(tmp_path / "course"),
            "--memory",
            "2",
        ],
        capture_output=True,
        text=True,
    )
    out, err = run.stdout, run.stderr
    with open(tmp_path / "course" / "grades.csv") as fh:
        scores = [
            classroom.Score(
                r["student"], r["chapter"], r["exercise"], float(r["score"]), float(r["max_score"]), r["refused"]
            )
            for r in csv.DictReader(fh)
        ]
    assert _lost(scores, "hog") == {"ch01_reward_eq11_tests"}
    assert classroom.table(scores) in out
    ran = cells(tmp_path / "course" / "autograded" / "hog" / classroom.ASSIGNMENT / "01_environment.ipynb")
    answer = next(c for c in ran if nbgrader(c).get("grade_id") == "ch01_reward_eq11")
    assert any(o.output_type == "error" and o.ename == "MemoryError" for o in answer.outputs)
    assert "nbgrader could not grade crash" in err, err[-2000:]
    for noise in ("SAWarning", "without encryption", "Warning: "):
        assert noise not in out + err, noise


def test_a_submission_writing_outside_its_folder_loses_only_that_exercise_and_writes_nothing(tmp_path):
    outside = tmp_path / "outside.txt"
    teacher_file = tmp_path / "teacher.txt"
    teacher_file.write_text("the teacher's")
    attacks = {
        "ch01_collision_share": f"open({str(outside)!r}, 'w').write('pwned')",
        "ch01_grasp_reward": f"open({str(teacher_file)!r}, 'a').write('pwned')",
    }
    mallory = _attacked(tmp_path, "mallory", attacks)
    scores = classroom.grade([mallory], tmp_path / "course")
    assert _lost(scores, "mallory") == {"ch01_collision_share_tests", "ch01_grasp_reward_tests"}
    assert not outside.exists() and teacher_file.read_text() == "the teacher's"
    ran = cells(tmp_path / "course" / "autograded" / "mallory" / classroom.ASSIGNMENT / "01_environment.ipynb")
    errors = [o for c in ran if nbgrader(c).get("grade_id") in attacks for o in c.outputs if o.output_type == "error"]
    assert len(errors) == 2 and all(o.ename in ("FileNotFoundError", "PermissionError", "OSError") for o in errors), (
        errors
    )


def test_the_kernel_has_no_network_and_its_own_home(tmp_path):
    """What the launcher gives a command, checked directly: the caps, a fresh HOME that is the working folder,
    and no route to any address."""
    probe = (
        "import os, resource, socket, sys\n"
        f"print(resource.getrlimit({sandbox.memory_limit()})[0], resource.getrlimit(resource.RLIMIT_CPU)[0])\n"
        "print(os.environ['HOME'] == os.getcwd(), os.listdir(os.getcwd()))\n"
        "try:\n    socket.create_connection(('192.0.2.1', 80), timeout=5)\nexcept OSError as e:\n"
        "    print(type(e).__name__, e.errno)\n"
    )
    cmd = sandbox.command(
        [sys.executable, "-c", probe], 3 << 30, 77, home_under=tmp_path, read_only=sandbox.python_paths()
    )
    lines = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()
    assert lines[0] == f"{3 << 30} 77"
    assert lines[1] == "True []"
    assert lines[2] == f"OSError {errno.ENETUNREACH}", lines


def test_a_command_past_the_cpu_cap_is_killed_by_the_kernel(tmp_path):
    """RLIMIT_CPU, soft and hard at 1 s: a busy loop is killed after one CPU second, long before its own 30 s
    (a kernel spinning where nbgrader's per-cell timeout cannot interrupt it dies the same way). Linux sends
    SIGKILL when the hard limit is reached, and the soft one's SIGXCPU only while below it."""
    spin = "import time\nt = time.process_time()\nwhile time.process_time() - t < 30:\n    pass\nprint('survived')"
    cmd = sandbox.command(
        [sys.executable, "-c", spin], 3 << 30, 1, home_under=tmp_path, read_only=sandbox.python_paths()
    )
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    killed = {128 + signal.SIGKILL, 128 + signal.SIGXCPU}  # bwrap exits with 128 + the signal that ended the command
    assert run.returncode in killed and "survived" not in run.stdout, (run.returncode, run.stdout)


def test_the_memory_cap_counts_memory_not_mapped_libraries(tmp_path):
    """PyPI's CUDA build of torch maps more than 4 GB of shared libraries on import, GPU or not; an
    address-space cap killed every kernel that imported it (all of chapters 04-09's points lost on Python
    3.13 in CI). A 3 GB read-only file mapping stands in for those libraries under a 1 GB cap: it must be
    allowed, while 2 GB of writable memory must not."""
    library = tmp_path / "libbig.so"
    with open(library, "wb") as fh:
        fh.truncate(3 << 30)  # sparse: no disk used
    probe = (
        "import mmap\n"
        f"with open({str(library)!r}, 'rb') as fh:\n"
        "    mapped = mmap.mmap(fh.fileno(), 0, prot=mmap.PROT_READ)\n"
        "print('mapped', len(mapped) >> 30)\n"
        "try:\n    bytearray(2 << 30)\nexcept MemoryError:\n    print('MemoryError')\n"
    )
    cmd = sandbox.command(
        [sys.executable, "-c", probe], 1 << 30, 60, home_under=tmp_path, read_only=[*sandbox.python_paths(), library]
    )
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert run.stdout.split("\n")[:2] == ["mapped 3", "MemoryError"], (run.stdout, run.stderr[-500:])


#: Wrong answers whose feedback page must say the cause in words, by student: (chapter, exercise, text of the
#: teacher's solution, the wrong version, the words).
NAMED_CAUSES = {
    "inverted_ratio": (
        "06a_trpo_pieces",
        "ch06_surrogate",
        "ratio = torch.exp(log_pi(theta) - log_pi(torch.as_tensor(theta_old)))",
        "ratio = torch.exp(log_pi(torch.as_tensor(theta_old)) - log_pi(theta))",
        "the gradient of L must be the policy gradient g",
    ),
    "no_damping": (
        "06b_trpo_assembled",
        "ch06_trpo_update",
        "Fvp = double_backward_fvp(policy, params, obs, old, config.cg_damping)",
        "Fvp = double_backward_fvp(policy, params, obs, old, 0.0)",
        "without damping",
    ),
    "sign_error": (
        "06b_trpo_assembled",
        "ch06_trpo_update",
        "return (ratio * advantages).mean(), mean_kl(old, dist)",
        "return -(ratio * advantages).mean(), mean_kl(old, dist)",
        "the sign of your surrogate",
    ),
}


def test_feedback_names_the_cause_of_a_wrong_answer(tmp_path):
    """The page of a wrong 6.2 carries the visible test's own message; a 6.8 without damping and one with its
    surrogate's sign flipped are named as such; and no page adds that the hidden check got no answer, which the
    visible test's failure already explains."""
    from vdtutorial.course.checks import NO_ANSWER

    for student, (chapter, _, right, wrong, _) in NAMED_CAUSES.items():
        text = classroom.chapters()[chapter].read_text()
        assert text.count(json.dumps(right)[1:-1]) == 1, student
        (tmp_path / "in" / student).mkdir(parents=True)
        (tmp_path / "in" / student / f"{chapter}.ipynb").write_text(
            text.replace(json.dumps(right)[1:-1], json.dumps(wrong)[1:-1])
        )
    scores = classroom.grade(sorted((tmp_path / "in").iterdir()), tmp_path / "course", workers=2)
    lost = {(s.student, s.exercise) for s in scores if s.score < s.max_score}
    assert lost == {(student, f"{exercise}_tests") for student, (_, exercise, *_) in NAMED_CAUSES.items()}, lost
    for student, (chapter, exercise, _, _, words) in NAMED_CAUSES.items():
        page = (tmp_path / "course" / "feedback" / student / f"{chapter}.md").read_text()
        said = page.split(f"## {exercise}\n", 1)[1]
        assert words in said and "is stubbed in grading" not in said, (student, page)
        # 6.8's visible tests compare with the library's TRPO, a stub in grading: they stop before their asserts
        visible = exercise != "ch06_trpo_update"
        assert not visible or "the visible tests raised AssertionError: " in said, (student, page)
        assert NO_ANSWER not in page, (student, page)


def test_feedback_quotes_a_comparisons_own_message_and_says_no_answer_only_when_nothing_else_did():
    """numpy.testing puts the test's ``err_msg`` after a blank line and a line of tolerances: the page quotes it. The
    hidden check's "no answer" is left out where the notebook showed why (an error in that exercise's cells)."""
    import numpy as np

    from vdtutorial.course.checks import NO_ANSWER
    from vdtutorial.course.feedback import error_message, report

    with pytest.raises(AssertionError) as raised:
        np.testing.assert_allclose([1.0, 2.0], [1.0, 3.0], err_msg="the gradient of L must be g")
    said = error_message(str(raised.value))
    assert said.startswith("the gradient of L must be g (Not equal to tolerance") and "Mismatch" not in said, said
    assert error_message("\nfirst words\nmore") == "first words" and error_message("") == ""
    rows = [
        classroom.Score("ann", "06a", f"{name}_tests", 0.0, 3.0, failed=(NO_ANSWER,)) for name in ("shown", "quiet")
    ]
    page = report("ann", "06a", rows, {"shown": ["the visible tests raised AssertionError: " + said]})
    shown, quiet = page.split("## shown\n")[1].split("## quiet\n")
    assert said in shown and NO_ANSWER not in shown and NO_ANSWER in quiet, page
