"""The grader against a hostile class: the sandbox seen from inside a kernel, one student who tries to stop the
grading, the options of ``classroom grade``. The commands that grade whole notebooks are ``pipeline`` tests."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import nbformat
import pytest

from vdtutorial.__main__ import main
from vdtutorial.course import classroom, sandbox

needs_sandbox = pytest.mark.skipif(sandbox.available() is not None, reason=f"no sandbox here: {sandbox.available()}")

#: What a kernel reports about its sandbox, as one JSON line (the same probe runs under the launcher and in a
#: graded cell). ``SECRET`` is a file of the grader's that it tries to read.
PROBE = """
import json, os
def _try(action):
    try:
        action()
        return "done"
    except OSError as exc:
        return type(exc).__name__
def _write(path):
    with open(path, "w") as fh:
        fh.write("x")
_found = {
    "uid": os.getuid(),
    "dev": _try(lambda: _write("/dev/vdtutorial_probe")),
    "proc_sys": [p for p in ("/proc/sys/kernel/core_pattern", "/proc/sys/vm/overcommit_ratio")
                 if os.access(p, os.W_OK)],
    "sys": os.path.exists("/sys") and os.listdir("/sys"),
    "pids": sorted(int(p) for p in os.listdir("/proc") if p.isdigit()),
    "secret": _try(lambda: open(SECRET).read()),
    "cgroup": [line.split()[1] for line in open("/proc/self/mounts") if line.split()[2].startswith("cgroup")],
}
print("PROBE " + json.dumps(_found))
"""


def _probe_result(text: str) -> dict:
    return json.loads(next(line for line in text.splitlines() if line.startswith("PROBE "))[len("PROBE ") :])


def _assert_confined(found: dict) -> None:
    assert found["dev"] != "done" and not Path("/dev/vdtutorial_probe").exists()
    assert found["proc_sys"] == [] and not found["sys"] and found["cgroup"] == []
    assert found["secret"] in ("FileNotFoundError", "PermissionError")
    assert max(found["pids"]) < 10, found["pids"]  # its own PID namespace: bwrap, the kernel and its children
    assert found["uid"] == sandbox.NOBODY
    if os.getuid() == 0:  # graded as root: the kernel's files are nobody's outside, not root's
        assert found["uid"] != 0


@needs_sandbox
def test_the_launcher_confines_a_command(tmp_path):
    """The sandbox alone, as the probe sees it: no host /dev, /proc/sys, /sys or cgroup fs, its own PID namespace,
    nothing of the grader's files; a process it leaves running ends with it."""
    secret = tmp_path / "source" / "solutions.txt"
    secret.parent.mkdir()
    secret.write_text("the teacher's")
    marker = f"{600 + os.getpid() % 1000}.25"  # a sleep no other process runs
    code = (
        f"SECRET = {str(secret)!r}\n"
        + PROBE
        + f"import subprocess\nsubprocess.Popen(['sleep', '{marker}'], start_new_session=True)\n"
    )
    cmd = sandbox.command(
        [sys.executable, "-c", code], 2 << 30, 60, home_under=tmp_path, read_only=sandbox.python_paths()
    )
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    _assert_confined(_probe_result(run.stdout))
    time.sleep(1)
    left = [p for p in os.listdir("/proc") if p.isdigit() and marker in _cmdline(p)]
    assert not left, "a process the sandboxed command started outlived it"


def _cmdline(pid: str) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


@pytest.mark.parametrize(
    "option, value",
    [
        ("--memory", "inf"),
        ("--memory", "nan"),
        ("--memory", "0"),
        ("--cpu-minutes", "1e300"),
        ("--cpu-minutes", "-1"),
        ("--timeout", "-5"),
        ("--timeout", "nan"),
        ("--workers", "0"),
        ("--workers", "1.5"),
        ("--wall-minutes", "inf"),
    ],
)
def test_a_limit_that_is_not_finite_and_positive_is_one_error_line_before_anything_is_written(
    option, value, tmp_path, capsys
):
    (tmp_path / "ann").mkdir()
    (tmp_path / "ann" / "10_what_reproduced.ipynb").write_bytes(classroom.chapters()["10_what_reproduced"].read_bytes())
    with pytest.raises(SystemExit) as stop:
        main(["classroom", "grade", str(tmp_path / "ann"), "--out", str(tmp_path / "course"), option, value])
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("[quick mode")]
    assert stop.value.code == 2 and len(err) == 1 and err[0].startswith(f"error: {option} must be"), err
    assert not (tmp_path / "course").exists()


def test_without_a_sandbox_grading_is_refused_unless_the_teacher_opts_out(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sandbox, "available", lambda: "bwrap not found")
    (tmp_path / "ann").mkdir()
    (tmp_path / "ann" / "10_what_reproduced.ipynb").write_bytes(classroom.chapters()["10_what_reproduced"].read_bytes())
    with pytest.raises(SystemExit) as stop:
        main(["classroom", "grade", str(tmp_path / "ann"), "--out", str(tmp_path / "course")])
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("[quick mode")]
    assert stop.value.code == 2 and len(err) == 1 and "bwrap not found" in err[0] and "--no-sandbox" in err[0]
    assert sandbox.SAFE_ROUTES in err[0] and not (tmp_path / "course").exists()


def test_a_table_graded_without_a_sandbox_says_so(tmp_path):
    scores = [classroom.Score("ann", "10_what_reproduced", "ch10_holm_tests", 3.0, 3.0, sandboxed=False)]
    assert classroom.table(scores).startswith("graded WITHOUT a sandbox (--no-sandbox)")
    with open(classroom.write_csv(scores, tmp_path / "grades.csv")) as fh:
        assert [row["sandbox"] for row in csv.DictReader(fh)] == ["NO"]


def _chapter_with(chapter: str, code_before_answers: dict[str, str] = (), extra_cell: str | None = None, at: int = 3):
    """The teacher's ``chapter`` (solved), with code put in front of some answers, and one more cell."""
    nb = nbformat.read(classroom.chapters()[chapter], as_version=4)
    for cell in nb.cells:
        grading = cell.metadata.get("nbgrader", {})
        if grading.get("solution") and grading.get("grade_id") in dict(code_before_answers):
            cell.source = dict(code_before_answers)[grading["grade_id"]] + "\n" + cell.source
    if extra_cell is not None:
        nb.cells.insert(at, nbformat.v4.new_code_cell(extra_cell))
    return nb


def _hand_in(folder: Path, student: str, chapter: str, nb) -> Path:
    (folder / student).mkdir(parents=True)
    nbformat.write(nb, folder / student / f"{chapter}.ipynb")
    return folder / student


@needs_sandbox
@pytest.mark.pipeline
def test_a_graded_cell_is_confined(tmp_path):
    """The probe as a cell of a submission of chapter 00, graded (as root where the tests run as root): the
    kernel cannot create a file in the host's /dev, write under /proc/sys or /sys, see a process outside its
    PID namespace, or read the course's source folder (the teacher's notebooks that ``grade`` copies there)."""
    course = tmp_path / "course"
    secret = course / "source" / classroom.ASSIGNMENT / "00_start_here.ipynb"
    cell = f"SECRET = {str(secret)!r}\n" + PROBE
    folder = _hand_in(tmp_path / "in", "mallory", "00_start_here", _chapter_with("00_start_here", extra_cell=cell))
    classroom.grade([folder], course, timeout=120, static_check=False)  # the sandbox alone, not the static check
    ran = nbformat.read(course / "autograded" / "mallory" / classroom.ASSIGNMENT / "00_start_here.ipynb", 4)
    printed = "".join(o.get("text", "") for c in ran.cells if c.cell_type == "code" for o in c.get("outputs", []))
    found = _probe_result(printed)
    assert secret.is_file()  # there, outside the sandbox
    _assert_confined(found)


#: Chapter 10 handed in by a class of five: two honest students (the teacher's solutions), and three who try to
#: stop the grading from a cell of their own: kill the process that runs their kernel, stop it, and hang past any
#: cell timeout (SIGINT ignored, so that no interrupt ends the cell).
CLASS_OF_FIVE = {
    "honest1": None,
    "honest2": None,
    "killer": "import os, subprocess\nprint(subprocess.run(['kill', '-9', str(os.getppid())]).returncode)\n",
    "stopper": "import os, subprocess\nprint(subprocess.run(['kill', '-STOP', str(os.getppid())]).returncode)\n",
    "hanger": "import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nwhile True:\n    time.sleep(1)\n",
}


@needs_sandbox
@pytest.mark.pipeline
def test_one_student_never_stops_the_class(tmp_path):
    """With two workers, a class of five in which one kills, one stops and one hangs is graded to the end within the
    per-submission budget: the honest students get full points, and so do the killer and the stopper, whose
    signals reach no process outside their sandbox; the hanger is cut off by its budget, with the reason in the
    table and grades.csv."""
    chapter = "10_what_reproduced"
    for student, cell in CLASS_OF_FIVE.items():
        _hand_in(tmp_path / "in", student, chapter, _chapter_with(chapter, extra_cell=cell, at=4))
    wall_minutes = 6.0
    start = time.monotonic()
    scores = classroom.grade(
        sorted((tmp_path / "in").iterdir()),
        tmp_path / "course",
        timeout=600,
        workers=2,
        limits=classroom.Limits(wall_minutes=wall_minutes),
        static_check=False,
    )
    took = time.monotonic() - start
    totals = {st: sum(s.score for s in scores if s.student == st) for st in CLASS_OF_FIVE}
    possible = sum(s.max_score for s in scores if s.student == "honest1")
    assert possible > 0
    assert totals["honest1"] == totals["honest2"] == totals["killer"] == totals["stopper"] == possible, totals
    assert totals["hanger"] == 0
    assert all(
        s.refused.startswith("grading did not finish: ") and "budget" in s.refused
        for s in scores
        if s.student == "hanger"
    )
    with open(tmp_path / "course" / "grades.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["student"] for r in rows if r["refused"].startswith("grading did not finish")} == {"hanger"}
    assert "grading did not finish" in classroom.table(scores)
    assert took < 3 * wall_minutes * 60, took  # five submissions, two at a time, none past its budget


@needs_sandbox
@pytest.mark.pipeline
def test_on_ray_a_hung_submission_costs_itself_alone(tmp_path):
    """On the Ray backend too, each submission is graded in a process of its own under its wall-clock budget: a
    submission that hangs past every cell timeout is cut off at its budget with the reason, and the honest one
    beside it gets its points (before, a Ray task graded in its own process with no budget, and waited)."""
    pytest.importorskip("ray")
    chapter = "01_environment"
    _hand_in(tmp_path / "in", "honest", chapter, _chapter_with(chapter))
    _hand_in(tmp_path / "in", "hanger", chapter, _chapter_with(chapter, extra_cell=CLASS_OF_FIVE["hanger"], at=4))
    wall_minutes = 2.0
    start = time.monotonic()
    scores = classroom.grade(
        sorted((tmp_path / "in").iterdir()),
        tmp_path / "course",
        timeout=600,
        workers=2,
        backend="ray",
        limits=classroom.Limits(wall_minutes=wall_minutes),
        static_check=False,
    )
    took = time.monotonic() - start
    totals = {st: sum(s.score for s in scores if s.student == st) for st in ("honest", "hanger")}
    possible = sum(s.max_score for s in scores if s.student == "honest")
    assert possible > 0 and totals == {"honest": possible, "hanger": 0}, totals
    assert all("budget" in s.refused for s in scores if s.student == "hanger")
    assert took < 2 * wall_minutes * 60, took


def _npz_bomb(path: Path, gigabytes: float) -> None:
    """A zip64 ``.npz`` whose one array is ``gigabytes`` of float64 zeros: a few MB on disk."""
    import zipfile

    import numpy as np

    count = int(gigabytes * 2**30) // 8
    header = {"descr": "<f8", "fortran_order": False, "shape": (count,)}
    chunk = bytes(64 << 20)
    with (
        zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive,
        archive.open("log_alpha.npy", "w", force_zip64=True) as fh,
    ):
        np.lib.format.write_array_header_2_0(fh, header)
        for start in range(0, count * 8, len(chunk)):
            fh.write(chunk[: min(len(chunk), count * 8 - start)])


def test_an_outputs_bomb_is_refused_before_it_is_decompressed(tmp_path):
    """A kernel's outputs file of a few MB that decompresses to 1.5 GB: the grader refuses it from the sizes the
    archive and the array declare, and its own memory does not grow by the bomb's size."""
    import resource

    from vdtutorial.course import checks

    _npz_bomb(checks.outputs_path(tmp_path, "ch04_svdo_layer"), 1.5)
    assert checks.outputs_path(tmp_path, "ch04_svdo_layer").stat().st_size < 16 << 20
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert classroom._outputs(tmp_path, "ch04_svdo_layer") is None
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) << 10  # Linux: kB
    assert grown < 256 << 20, grown
    checks.save(checks.outputs_path(tmp_path, "ch04_svdo_layer"), {"log_alpha": [[1.0, 2.0]]})
    assert classroom._outputs(tmp_path, "ch04_svdo_layer")["log_alpha"].shape == (1, 2)  # an honest one is read


def test_a_students_error_message_is_text_not_markup_in_the_feedback_page(tmp_path):
    """An answer that raises with HTML and Markdown in its message: the student's page shows it as written."""
    from vdtutorial.course import feedback

    hostile = "<script>alert(1)</script> [prize](http://example.com) **bold** `code` | table |"
    cell = nbformat.v4.new_code_cell("raise ValueError(...)", metadata={"nbgrader": {"grade_id": "ch10_holm"}})
    cell.outputs = [nbformat.v4.new_output("error", ename="ValueError", evalue=hostile, traceback=[])]
    autograded = tmp_path / "autograded" / "eve" / classroom.ASSIGNMENT / "10_what_reproduced.ipynb"
    autograded.parent.mkdir(parents=True)
    nbformat.write(nbformat.v4.new_notebook(cells=[cell]), autograded)
    scores = [classroom.Score("eve", "10_what_reproduced", "ch10_holm_tests", 0.0, 3.0, failed=("[x](y)",))]
    page = feedback.write_reports(scores, tmp_path, classroom.ASSIGNMENT)[0].read_text()
    assert "<script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "[prize](" not in page and r"\[prize\](http://example.com)" in page
    assert r"\*\*bold\*\* \`code\` \| table \|" in page and r"\[x\](y)" in page


def test_the_kernel_keeps_the_graders_vector_kernel_pins():
    """A check compares the sandboxed kernel's numbers with the grader's: both must use the same CPU kernels."""
    from vdtutorial.runner.kernels import PINNED

    assert set(PINNED) <= set(sandbox.KEPT_ENV)


def _chapter_answering(chapter: str, answers: dict[str, str], before: dict[str, str] = ()):
    """The teacher's ``chapter`` (solved), with some answer cells replaced by ``answers`` (by exercise) and code put
    in front of others (``before``)."""
    nb = _chapter_with(chapter, before)
    for cell in nb.cells:
        grading = cell.metadata.get("nbgrader", {})
        if grading.get("solution") and grading.get("grade_id") in answers:
            cell.source = answers[grading["grade_id"]]
    return nb


_STOLEN_COMPACT = "from vdtutorial.analysis.compact import compact\ndef my_compact(net):\n    return compact(net)\n"
#: Chapter 04 handed in by students who solve 4.1 themselves and take the library's layer (4.2) and compaction (4.3),
#: each by two routes that no reading of the answer's names sees: (answers by exercise, code put before answers).
STEALERS = {
    "crosscell_pkgutil": (
        {
            "ch04_svdo_layer": "import pkgutil\n"
            "MyLinearSVDO = pkgutil.resolve_name('vdtutorial.vd:' + 'Linear' + 'SVDO')\n",
            "ch04_compact": "def my_compact(net):\n    return _library_compact(net)\n",
        },
        {"ch04_gaussian_dropout": "from vdtutorial.analysis.compact import compact as _library_compact"},
    ),
    "pickle_sysmodules": (
        {
            "ch04_svdo_layer": "from sys import modules as M\nimport vdtutorial.vd\n"
            "MyLinearSVDO = getattr(M['vdtutorial.vd'], 'Linear' + 'SVDO')\n",
            "ch04_compact": "import pickle\nmy_compact = pickle.loads(b'cvdtutorial.analysis.compact\\ncompact\\n.')\n",
        },
        {},
    ),
    "encoded_alias": (
        {
            "ch04_svdo_layer": "LinearSVDO = LinearSVDO if True else None\nMyLinearSVDO = LinearSVDO\n",
            "ch04_compact": "import base64\nexec(base64.b64decode({!r}).decode())\n".format(
                __import__("base64").b64encode(_STOLEN_COMPACT.encode())
            ),
        },
        {},
    ),
    "importlib_runpy": (
        {
            "ch04_svdo_layer": "import runpy\nMyLinearSVDO = runpy.run_module('vdtutorial.vd')['LinearSVDO']\n",
            "ch04_compact": "import importlib\n"
            "my_compact = getattr(importlib.import_module('vdtutorial.analysis.' + 'compact'), 'compact')\n",
        },
        {},
    ),
}


#: Other chapters handed in by one student each, who takes the library's pieces as the answers of some exercises
#: (their answers, by exercise) and solves the others (the teacher's answers): student -> (chapter, answers, code
#: put before answers). 01: the reaching env's goal test by a name built from strings (pkgutil), the grasping tilt by
#: an import in 1.2's cell. 02: eq. 9 imported in 2.1's cell, eq. 10 by pkgutil (the pieces IKExpert is built on).
#: 06a: the conjugate gradient, Fisher-vector product and GAE imported in the REINFORCE cell (6.1) and handed back
#: as 6.3-6.5's answers. 07: the policy's pruning by pkgutil. 09: DAgger's mixture by pkgutil.
TAKEN_ELSEWHERE = {
    "taken_01": (
        "01_environment",
        {
            "ch01_reward_eq11": "import pkgutil\nfrom types import SimpleNamespace\n"
            "_status = pkgutil.resolve_name('vdtutorial.envs.reach:JacoReachEnv.' + '_goal' + '_status')\n"
            "def eq11_terms(scene, q_old, action):\n"
            "    q_old = np.asarray(q_old, dtype=float)\n"
            "    failure = scene.path_in_collision(q_old, np.clip(q_old + action, scene.lower, scene.upper))\n"
            "    success, info = _status(SimpleNamespace(scene=scene))\n"
            "    return {'-|a|': -float(np.linalg.norm(action)), '-d_t': -info['distance'],\n"
            "            '+c1 succ': C_SUCCESS * (success and not failure), '-c2 fail': -C_FAILURE * failure}\n",
            "ch01_grasp_reward": "def grasp_outcome(scene, failure):\n"
            "    hand, approach = scene.tcp_pose()\n"
            "    near = np.linalg.norm(hand - grasp_point(scene.cup_position)) < POSITION_TOLERANCE\n"
            "    success = bool(near and _tilt(approach) < TILT_TOLERANCE_DEG and not failure)\n"
            "    return -1.0 + 25.0 * success - 25.0 * failure, success or bool(failure)\n",
        },
        {"ch01_collision_share": "from vdtutorial.envs.grasp import tilt_deg as _tilt"},
    ),
    "expert_02": (
        "02_ik_expert",
        {
            "ch02_nearest_goal": "def my_nearest_goal(G, j, lower, upper):\n    return _eq9(G, j, lower, upper)\n",
            "ch02_step_towards": "import pkgutil\n"
            "my_step = pkgutil.resolve_name('vdtutorial.expert:' + 'step_' + 'towards')\n",
        },
        {"ch02_goal_set": "from vdtutorial.expert import nearest_goal as _eq9"},
    ),
    "pkgutil_07": (
        "07_finetuning",
        {
            "ch07_prune": "import pkgutil\n"
            "def prune_for_rl(policy, threshold=THRESHOLD):\n"
            "    prune = pkgutil.resolve_name('vdtutorial.policy:GaussianPolicy.' + 'prune' + '_')\n"
            "    return prune(copy.deepcopy(policy), threshold)\n",
        },
        {},
    ),
    "crosscell_06a": (
        "06a_trpo_pieces",
        {
            "ch06_conjugate_gradient": "def my_cg(Avp, b, iters):\n    return _cg(Avp, b, iters)\n",
            "ch06_fisher_vector_product": "my_fvp = _fvp\n",
            "ch06_gae": "def my_gae(*args):\n    return _gae(*args)\n",
        },
        {
            "ch06_reinforce": "from vdtutorial.trust_region import conjugate_gradient as _cg\n"
            "from vdtutorial.trust_region import double_backward_fvp as _fvp\n"
            "from vdtutorial.trpo import gae as _gae"
        },
    ),
    "resolved_09": (
        "09_beyond_the_paper",
        {
            "ch09_dagger_plan": "import pkgutil\n\n\ndef dagger_plan(k, policy, demos):\n"
            "    mix = pkgutil.resolve_name('vdtutorial.beyond.dagger:' + 'mix' + 'ture')\n"
            "    return mix(policy, BETA**k), {'beta': BETA**k}\n"
        },
        {},
    ),
}


@needs_sandbox
@pytest.mark.pipeline
def test_the_librarys_pieces_are_stubs_in_the_kernel_whatever_the_route(tmp_path):
    """Graded without the static check (the stubs alone), each of these students scores 4.1, which they solved, and 0
    for the library's layer and compaction they took: by an import in another exercise's cell, a name built from
    strings (pkgutil), sys.modules, pickle of a global reference, code decoded and run, an alias of the library's
    class, importlib and runpy; and each student of another chapter (``TAKEN_ELSEWHERE``) keeps the points of the
    exercises they solved and scores 0 for those whose library piece they took. The table and grades.csv say that
    the answer called a stub."""
    chapter = "04_sparse_variational_dropout"
    for student, (answers, before) in STEALERS.items():
        _hand_in(tmp_path / "in", student, chapter, _chapter_answering(chapter, answers, before))
    for student, (other, answers, before) in TAKEN_ELSEWHERE.items():
        _hand_in(tmp_path / "in", student, other, _chapter_answering(other, answers, before))
    scores = classroom.grade(
        sorted((tmp_path / "in").iterdir()), tmp_path / "course", timeout=600, workers=2, static_check=False
    )
    got = {(s.student, s.exercise): s for s in scores}
    for student in STEALERS:
        own = got[student, "ch04_gaussian_dropout_tests"]
        assert own.score == own.max_score > 0, own
        for exercise, stub in (("ch04_svdo_layer", "SVDOLayer"), ("ch04_compact", "compact")):
            taken = got[student, f"{exercise}_tests"]
            assert taken.score == 0, taken
            assert "called a stub: the library's vdtutorial." in taken.refused and stub in taken.refused, taken
    for student, (_, answers, _) in TAKEN_ELSEWHERE.items():
        graded = [s for s in scores if s.student == student]
        assert {s.exercise.removesuffix("_tests") for s in graded} > set(answers), graded
        for score in graded:
            if score.exercise.removesuffix("_tests") in answers:
                assert score.score == 0 and "called a stub: the library's vdtutorial." in score.refused, score
            else:
                assert score.score == score.max_score > 0, score
    with open(tmp_path / "course" / "grades.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if "called a stub" in r["refused"]]
    assert {r["student"] for r in rows} == {*STEALERS, *TAKEN_ELSEWHERE}
    assert len(rows) == 2 * len(STEALERS) + sum(len(answers) for _, answers, _ in TAKEN_ELSEWHERE.values())
    assert "is stubbed in grading" in classroom.table(scores)


@pytest.mark.pipeline
def test_without_the_sandbox_the_stubbed_copy_still_comes_first(tmp_path):
    """``--no-sandbox`` shows the kernel no copy at the package's own path, but puts the stubbed copy first on its
    path: the routes of one of the students above still reach only the stubs, and the table says what was given up."""
    chapter, student = "04_sparse_variational_dropout", "crosscell_pkgutil"
    _hand_in(tmp_path / "in", student, chapter, _chapter_answering(chapter, *STEALERS[student]))
    limits = classroom.Limits(sandbox=False)
    scores = classroom.grade([tmp_path / "in" / student], tmp_path / "course", limits=limits, static_check=False)
    got = {s.exercise: s for s in scores}
    assert got["ch04_gaussian_dropout_tests"].score == got["ch04_gaussian_dropout_tests"].max_score > 0
    for exercise in ("ch04_svdo_layer", "ch04_compact"):
        assert got[f"{exercise}_tests"].score == 0 and "called a stub" in got[f"{exercise}_tests"].refused
    assert classroom.table(scores).startswith("graded WITHOUT a sandbox (--no-sandbox)")


@needs_sandbox
@pytest.mark.pipeline
def test_an_interrupted_grading_resumes_where_it_stopped(tmp_path):
    """``classroom grade`` keeps each submission's result as it finishes: interrupted (Ctrl-C) after the first, and
    run again, it grades only the others, and every student gets the points; a submission changed since is graded
    again."""
    chapter, students = "10_what_reproduced", ("ann", "bob", "cid")
    for student in students:
        _hand_in(tmp_path / "in", student, chapter, _chapter_with(chapter))
    course = tmp_path / "course"
    argv = [sys.executable, "-m", "vdtutorial", "classroom", "grade", *(str(tmp_path / "in" / s) for s in students)]
    argv += ["--out", str(course), "--workers", "1"]
    deadline = time.monotonic() + 900
    with open(tmp_path / "first.log", "w") as out:
        first = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT)
        while not list(course.glob("results/*/*.json")) and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        first.send_signal(signal.SIGINT)
        first.wait(timeout=120)
    kept = {path: path.stat().st_mtime_ns for path in course.glob("results/*/*.json")}
    assert first.returncode != 0 and 1 <= len(kept) < len(students), (first.returncode, kept)
    assert not (course / "grades.csv").exists()

    again = subprocess.run(argv, capture_output=True, text=True, timeout=1800, check=False)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"resuming: {len(kept)} submissions were graded by an earlier run" in again.stderr
    assert {path: path.stat().st_mtime_ns for path in kept} == kept, "a kept result was graded again"
    with open(course / "grades.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["student"] for r in rows} == set(students)
    assert all(float(r["score"]) == float(r["max_score"]) > 0 for r in rows), rows

    changed = next(iter(kept)).parent.name  # a student who hands in again is graded again
    nb = _chapter_with(chapter, extra_cell="print('handed in again')")
    nbformat.write(nb, tmp_path / "in" / changed / f"{chapter}.ipynb")
    third = subprocess.run(argv, capture_output=True, text=True, timeout=1800, check=False)
    assert third.returncode == 0 and f"resuming: {len(students) - 1} submissions" in third.stderr, third.stderr[-2000:]


def _descendants(pid: int) -> set[int]:
    """The live processes under ``pid`` (read from /proc: each one's parent; a zombie counts as gone)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            state, parent = stat.read_text().rsplit(")", 1)[1].split()[:2]
        except (OSError, ValueError):
            continue
        if state != "Z":
            parents[int(stat.parent.name)] = int(parent)
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@needs_sandbox
@pytest.mark.pipeline
def test_a_grader_killed_outright_leaves_no_process_behind_and_a_rerun_resumes(tmp_path):
    """``kill -9`` of the grader while one submission's kernel sleeps: its grading process, the sandbox and the
    kernel end with it (they would otherwise grade on, or sleep, for nobody), and the rerun keeps what was graded."""
    chapter = "10_what_reproduced"
    _hand_in(tmp_path / "in", "ann", chapter, _chapter_with(chapter))
    _hand_in(tmp_path / "in", "bob", chapter, _chapter_with(chapter, extra_cell="import time\ntime.sleep(3600)"))
    course = tmp_path / "course"
    argv = [sys.executable, "-m", "vdtutorial", "classroom", "grade", str(tmp_path / "in" / "ann")]
    argv += [str(tmp_path / "in" / "bob"), "--out", str(course), "--workers", "2"]
    deadline = time.monotonic() + 900
    with open(tmp_path / "first.log", "w") as out:
        first = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT)
        while not list(course.glob("results/ann/*.json")) and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        under = _descendants(first.pid)
        first.kill()
        first.wait(timeout=60)
    assert under and not list(course.glob("results/bob/*.json")), (tmp_path / "first.log").read_text()[-2000:]
    gone_by = time.monotonic() + 30
    while any(_alive(p) for p in under) and time.monotonic() < gone_by:
        time.sleep(0.5)
    left = {p: Path(f"/proc/{p}/cmdline").read_bytes()[:200] for p in under if _alive(p)}
    assert not left, left

    nbformat.write(_chapter_with(chapter), tmp_path / "in" / "bob" / f"{chapter}.ipynb")  # bob hands in again
    again = subprocess.run(argv, capture_output=True, text=True, timeout=1800, check=False)
    assert again.returncode == 0 and "resuming: 1 submissions were graded" in again.stderr, again.stderr[-2000:]
    with open(course / "grades.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["student"] for r in rows} == {"ann", "bob"}
    assert all(float(r["score"]) == float(r["max_score"]) > 0 for r in rows), rows
