"""The classroom edition: release the student notebooks and autograde submissions with nbgrader.

The chapters in ``notebooks/`` are the teacher's edition: every exercise is an nbgrader "autograded answer"
cell (the solution between ``### BEGIN SOLUTION`` / ``### END SOLUTION``), then an "autograded tests" cell with
points, visible asserts and hidden tests. This module lays out an nbgrader course directory and calls nbgrader's steps,

* :func:`release` -- ``generate_assignment``: solutions become ``# YOUR CODE HERE`` stubs, hidden tests
  and outputs are removed, cells are locked and checksummed;
* :func:`grade` -- ``generate_assignment`` (which records the exercises and their points in the SQLite
  gradebook) then ``autograde`` per submission: each runs on a fresh kernel with nbgrader's per-cell
  timeout, errors in a cell are recorded in that cell. An exercise's points are decided outside that kernel:
  its hidden tests only run the student's function on inputs the grader drew for this submission, and the
  grader compares the results with the library's in its own process (:mod:`vdtutorial.course.checks`).
  Submissions are graded several at once, each in a course folder of its own (a process of its own under a
  wall-clock budget, :mod:`vdtutorial.course.grading_process`, started by this process or by a Ray task), and
  their points are written into the
  one gradebook by the grading process alone. Before anything
  runs, the answer cells are read (:func:`refusals`, :mod:`vdtutorial.course.answer_rules`): an answer that
  uses the library's piece its exercise rebuilds scores 0 there; one that could change the tests makes the
  whole notebook score 0. The kernel imports a copy of the package in which the pieces of the chapter's exercises
  in :data:`vdtutorial.course.stubs.STUBS` are stubs: for those, that, not the reading, keeps them out of an answer.
  Each student gets a report without the hidden checks (:mod:`vdtutorial.course.feedback`).

Each kernel is bounded (:class:`Limits`, :mod:`vdtutorial.course.sandbox`): memory and CPU-time caps, in a
bubblewrap sandbox that shows it the Python environment and the package read-only, a private home, and nothing
else (where no sandbox can be made, ``classroom grade`` refuses unless told ``--no-sandbox``, :data:`SAFETY_NOTE`);
kernels talk to nbgrader over Unix sockets.
Command line: ``python -m vdtutorial classroom release OUT`` and ``... classroom grade SUBMISSIONS...``.

Not taught in a chapter: the teacher's tool (notebooks/TEACHING.md).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import re
import secrets
import shutil
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

from vdtutorial.settings import QUICK_ENV, shipped_dir

#: The nbgrader assignment that holds every chapter.
ASSIGNMENT = "vdtutorial"
#: Seconds a single cell may run during autograding before nbgrader interrupts it. Quick-mode cells take
#: seconds; the longest (a live TRPO run) about a minute on a busy 2-core machine.
CELL_TIMEOUT = 300
#: The largest notebook the grader parses (a submission, or a graded one with its outputs): bytes.
MAX_NOTEBOOK_BYTES = 64 << 20
#: The wall-clock budget (minutes) of one submission's grading with ``--full`` (chapters with live training runs).
FULL_WALL_MINUTES = 360.0
SAFETY_NOTE = (
    "the submissions run with your rights to files, network and processes. Grade in a container or "
    "a throwaway account, as nbgrader's documentation advises."
)


@dataclass(frozen=True)
class Limits:
    """What one submission's kernel may use: memory and CPU time, and ``sandbox``: whether it runs in the
    bubblewrap sandbox (:mod:`vdtutorial.course.sandbox`; ``False`` only when the teacher asked for
    ``--no-sandbox``)."""

    memory_gb: float = 4.0
    cpu_minutes: float = 60.0
    sandbox: bool = True
    wall_minutes: float = 30.0  # one submission's grading, all of it, measured from outside


class ClassroomError(Exception):
    """A problem the user can fix (bad path, unknown chapter, a notebook of another edition)."""


def available_cores() -> int:
    """The cores this process may run on (a container's or a batch job's share, not the machine's count)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def notebooks_dir() -> Path:
    """The teacher's edition: the shipped notebooks (a clone's ``notebooks/``, or the copy an installed wheel
    carries)."""
    return shipped_dir() / "notebooks"


def chapters(source: Path | None = None) -> dict[str, Path]:
    """The chapter notebooks of ``source`` (default: :func:`notebooks_dir`) by name (``"03_demonstrations"``
    -> its path; a chapter in parts is one notebook per part, ``"06a_trpo_pieces"``, ``"06b_trpo_assembled"``)."""
    source = Path(source) if source is not None else notebooks_dir()
    if not source.is_dir():
        raise ClassroomError(f"no notebooks folder at {source}: pass --source with the teacher's notebooks")
    found = {p.stem: p for p in sorted(source.glob("[0-9][0-9]*_*.ipynb"))}  # a chapter in parts: 06a_..., 06b_...
    if not found:
        raise ClassroomError(f"{source} holds no chapter notebooks (NN_name.ipynb or NNa_name.ipynb)")
    return found


def grade_ids(path: Path) -> list[str]:
    """The ``grade_id`` of every nbgrader cell of a notebook, in order."""
    import nbformat

    if Path(path).stat().st_size > MAX_NOTEBOOK_BYTES:
        raise ClassroomError(f"{path} is larger than {MAX_NOTEBOOK_BYTES >> 20} MB: no chapter notebook is")
    try:
        nb = nbformat.read(path, as_version=4)
    except Exception as exc:  # nbformat raises several types for files that are not notebooks
        raise ClassroomError(f"{path} is not a Jupyter notebook ({type(exc).__name__})") from None
    return [c.metadata["nbgrader"]["grade_id"] for c in nb.cells if "grade_id" in c.metadata.get("nbgrader", {})]


def _api(course: Path, timeout: int, sockets: Path | None = None, exchange=None):
    """An nbgrader API object for the course directory ``course`` (gradebook ``course/gradebook.db``).
    With ``sockets`` (a folder), kernels talk over Unix sockets made there, where the system has them: no
    TCP port, and no "running over TCP without encryption" warning from each kernel. ``exchange``: a
    :class:`_Exchange` whose hooks run before and after each cell the kernel executes."""
    from nbgrader.apps import NbGraderAPI
    from traitlets.config import Config

    config = Config()
    config.CourseDirectory.root = str(course)
    config.CourseDirectory.course_id = ASSIGNMENT
    config.CourseDirectory.db_url = f"sqlite:///{course / 'gradebook.db'}"
    config.Execute.timeout = timeout
    if sockets is not None and os.name == "posix":
        config.KernelManager.transport = "ipc"
        config.KernelManager.ip = str(sockets / "kernel")
    if exchange is not None:  # nbgrader's Execute takes nbclient's on_cell_executed for itself: one hook does both
        # a function, not the bound method: traitlets deep-copies its config, and a method's copy copies its object
        config.Execute.on_cell_execute = lambda **cell: exchange.before(**cell)
    return NbGraderAPI(config=config)


class _Exchange:
    """What the kernel and the grader pass each other, one exercise at a time, in the order of the chapter: an
    exercise's inputs appear in the exchange folder just before its tests cell runs, and its outputs leave it for a
    folder of the grader's (``sealed``), with its inputs, before the next cell runs (:meth:`before` does both, as
    each cell starts; :meth:`after` once the notebook ended). So nothing a later exercise's check hands the kernel
    (6.8's stand-in line search) exists while an earlier one is judged, and no later cell can rewrite an earlier
    exercise's outputs. A tests cell out of order (a copy of a later one, moved up) gets no inputs."""

    def __init__(self, exchange: Path, sealed: Path, inputs: dict[str, dict]):
        from vdtutorial.course import checks

        self.checks, self.exchange, self.sealed = checks, exchange, sealed
        self.order, self.inputs, self.open = list(inputs), inputs, None

    def _exercise(self, cell) -> str | None:
        """The exercise whose turn it is, if ``cell`` is its tests cell."""
        done = len(list(self.sealed.iterdir()))
        grading = cell.get("metadata", {}).get("nbgrader", {})
        if done < len(self.order) and grading.get("grade_id") == f"{self.order[done]}_tests":
            return self.order[done]
        return None

    def before(self, cell, **_) -> None:
        self.after()
        exercise = self._exercise(cell)
        if exercise is not None:
            self.checks.outputs_path(self.exchange, exercise).unlink(missing_ok=True)
            self.checks.save(self.checks.inputs_path(self.exchange, exercise), self.inputs[exercise])
            self.open = exercise

    def after(self, **_) -> None:
        exercise, self.open = self.open, None
        if exercise is None:
            return
        self.checks.inputs_path(self.exchange, exercise).unlink(missing_ok=True)
        outputs = self.checks.outputs_path(self.exchange, exercise)
        folder = self.sealed / exercise
        folder.mkdir()  # the exercise's turn is over, whatever came back
        if outputs.is_file() or outputs.is_symlink():
            os.replace(outputs, folder / outputs.name)

    def outputs(self, exercise: str) -> dict | None:
        return _outputs(self.sealed / exercise, exercise)


def _generate(
    course: Path,
    source: Path,
    names: list[str],
    timeout: int = CELL_TIMEOUT,
    sockets: Path | None = None,
    grading: bool = False,
):
    """Copy the teacher's chapters ``names`` into ``course/source`` and run nbgrader's generate_assignment; for
    ``grading``, with each tests cell's hidden tests moved first (:func:`hidden_tests_first`)."""
    found = chapters(source)
    src = course / "source" / ASSIGNMENT
    src.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copy(found[name], src / f"{name}.ipynb")
        if grading:
            hidden_tests_first(src / f"{name}.ipynb")
    api = _api(course, timeout, sockets)
    with _environment(PATH=_path_with_our_scripts()):
        result = api.generate_assignment(ASSIGNMENT)
    if not result["success"]:
        raise ClassroomError(f"nbgrader could not generate the assignment:\n{result.get('error') or result['log']}")
    return api


_HIDDEN = re.compile(r"^### BEGIN HIDDEN TESTS\n.*?^### END HIDDEN TESTS\n?", re.M | re.S)


def hidden_tests_first(path: Path) -> None:
    """Rewrite the notebook at ``path`` so that each tests cell runs its hidden tests (the trusted check's probe)
    before its visible ones. The visible tests compare with the library's piece, which the grading kernel has as a
    stub (:mod:`vdtutorial.course.stubs`): they raise there, and would stop the cell before its check ran. The
    points never came from them (:mod:`vdtutorial.course.checks`)."""
    import nbformat

    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        grading = cell.metadata.get("nbgrader", {})
        if cell.cell_type == "code" and grading.get("grade") and not grading.get("solution"):
            text = cell.source if cell.source.endswith("\n") else cell.source + "\n"
            if hidden := _HIDDEN.search(text):
                cell.source = (hidden.group(0).rstrip("\n") + "\n" + _HIDDEN.sub("", text, count=1)).rstrip("\n")
    nbformat.write(nb, path)


def release(out, source: Path | None = None, force: bool = False) -> list[Path]:
    """Write the student edition of every chapter into the folder ``out``; returns the notebook paths.

    nbgrader's generate_assignment does the work (solutions -> stubs, hidden tests and outputs removed).
    """
    source = Path(source) if source is not None else notebooks_dir()
    out = Path(out)
    names = list(chapters(source))
    clash = [n for n in names if (out / f"{n}.ipynb").exists()]
    if clash and not force:
        raise ClassroomError(
            f"{out} already holds {clash[0]}.ipynb (and {len(clash) - 1} more): choose an empty folder or pass --force"
        )
    with tempfile.TemporaryDirectory(prefix="vdtutorial_release_") as tmp:
        _generate(Path(tmp), source, names)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name in names:
            shutil.copy(Path(tmp) / "release" / ASSIGNMENT / f"{name}.ipynb", out / f"{name}.ipynb")
            written.append(out / f"{name}.ipynb")
    return written


@dataclass(frozen=True)
class Submission:
    """One submitted chapter notebook: ``student`` is the name of the folder the file sits in."""

    student: str
    chapter: str
    path: Path


def collect(paths, source: Path | None = None) -> list[Submission]:
    """Check the submitted files and say whose and which chapter each is.

    A path is a notebook ``STUDENT/NN_chapter.ipynb`` or a folder ``STUDENT/`` of such notebooks. Each must
    be a notebook, be named after a chapter, and carry exactly the exercises of that chapter (a notebook of
    another edition, or one whose exercise cells were deleted, is refused before anything runs).
    """
    source = Path(source) if source is not None else notebooks_dir()
    found = chapters(source)
    files = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            files += sorted(path.glob("*.ipynb"))
        elif path.is_file():
            files.append(path)
        else:
            raise ClassroomError(f"{path}: no such file or folder")
    if not files:
        raise ClassroomError("no notebooks to grade")
    subs, seen = [], set()
    for path in files:
        if path.suffix != ".ipynb":
            raise ClassroomError(f"{path} is not a notebook (.ipynb)")
        if path.stem not in found:
            raise ClassroomError(f"{path}: there is no chapter {path.stem!r} (chapters: {', '.join(found)})")
        student = re.sub(r"[^A-Za-z0-9_.-]", "_", path.resolve().parent.name)
        expected, got = grade_ids(found[path.stem]), grade_ids(path)
        if set(got) != set(expected):
            missing = sorted(set(expected) - set(got)) or sorted(set(got) - set(expected))
            raise ClassroomError(
                f"{path} is not from this edition of {path.stem} (exercise cells differ: "
                f"{', '.join(missing[:3])}): submit the notebook released by `classroom release`"
            )
        if (student, path.stem) in seen:
            raise ClassroomError(f"two submissions of {path.stem} for student {student!r}")
        seen.add((student, path.stem))
        subs.append(Submission(student, path.stem, path))
    return subs


def _bounded_kernels(scratch: Path, limits: Limits, writable: list[Path] = (), exercises=()) -> dict[str, str]:
    """Make the ``python3`` kernel that nbgrader starts a bounded one: a kernelspec in ``scratch`` whose
    command is the :mod:`vdtutorial.course.sandbox` launcher in front of ipykernel, each kernel in its own folder
    under ``scratch/homes``; ``writable``: more folders it may write. The sandbox shows the kernel this Python's
    environment and the course package (:func:`_library_mounts`), read-only, and nothing else of this machine's
    files; the package is a copy in which the pieces that ``exercises`` rebuild are stubs
    (:func:`vdtutorial.course.stubs.stubbed_copy`), shown at the package's own path. Returns the environment that
    makes Jupyter find the kernelspec first and keep its connection files and sockets in ``scratch/runtime`` (which
    the kernels may write, to make their sockets). Windows has no ``setrlimit``: there the kernels run unbounded
    (``classroom grade`` refuses unless told ``--no-sandbox``)."""
    from vdtutorial.course import sandbox, stubs

    if os.name != "posix":
        return {}
    homes, runtime, spec = scratch / "homes", scratch / "runtime", scratch / "kernels" / "python3"
    for folder in (homes, runtime, spec, scratch / "empty"):
        folder.mkdir(parents=True)
    library = stubs.stubbed_copy(scratch / "library" / "vdtutorial", exercises)
    kernel = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    argv = sandbox.command(
        kernel,
        max(1, int(limits.memory_gb * 2**30)),
        max(1, int(limits.cpu_minutes * 60)),
        home_under=homes,
        read_only=[*sandbox.python_paths(), *_library_mounts(scratch / "empty", library)],
        writable=[runtime, *writable],
        given=["{connection_file}"],
        sandboxed=limits.sandbox,
    )
    # A timed-out cell is interrupted by a message the kernel answers itself: a signal sent from outside reaches
    # only the launcher, since the sandbox runs the kernel in a session and PID namespace of its own.
    spec_json = {"argv": argv, "display_name": "Python 3 (bounded grading)", "language": "python"}
    (spec / "kernel.json").write_text(json.dumps({**spec_json, "interrupt_mode": "message"}))
    search = [str(scratch)] + [p for p in os.environ.get("JUPYTER_PATH", "").split(os.pathsep) if p]
    found = {"JUPYTER_PATH": os.pathsep.join(search), "JUPYTER_RUNTIME_DIR": str(runtime)}
    if not limits.sandbox:  # no mount to hide the original behind: the copy comes first on the kernel's path
        found["PYTHONPATH"] = os.pathsep.join(
            [str(library.parent), *os.environ.get("PYTHONPATH", "").split(os.pathsep)]
        )
    return found


def _library_mounts(empty: Path, library: Path | None = None) -> list[tuple[Path, Path]]:
    """What a kernel sees of the course package, as (source, destination) pairs for the sandbox: the package
    folder at its own path (``library`` there instead when given: the stubbed copy), and the shipped data the
    chapters read (a clone's ``data/`` with the ``pyproject.toml`` that marks the clone); never the teacher's
    notebooks (a clone's ``notebooks/`` is not shown, an installed copy's ``book/notebooks`` is covered by the
    empty folder ``empty``), nor anything else of the clone."""
    import vdtutorial
    from vdtutorial.settings import INSTALLED_COPY

    package = Path(vdtutorial.__file__).resolve().parent
    mounts = [(library or package, package)]
    if shipped_dir() == package.parent:
        mounts += [
            (package.parent / "data", package.parent / "data"),
            (package.parent / "pyproject.toml", package.parent / "pyproject.toml"),
        ]
    if (INSTALLED_COPY / "notebooks").is_dir():
        mounts.append((empty, INSTALLED_COPY / "notebooks"))
    return mounts


@contextlib.contextmanager
def _quiet():
    """Hide what is not the teacher's business: SQLAlchemy's session warnings from inside nbgrader's
    gradebook (``SAWarning``). Errors, and warnings of other kinds, still show."""
    from sqlalchemy.exc import SAWarning

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=SAWarning)
        yield


def _path_with_our_scripts() -> str:
    """PATH with this Python's scripts folder first: nbgrader opens its gradebook by running the ``alembic``
    command, which is found only if the environment was activated (not when ``.venv/bin/python`` is called)."""
    return os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])


@contextlib.contextmanager
def _environment(**values):
    """Set environment variables for the kernels nbgrader starts (they inherit ours), then restore."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@dataclass(frozen=True)
class Score:
    """Points of one exercise (one autograded-tests cell) of one student's chapter."""

    student: str
    chapter: str
    exercise: str
    score: float
    max_score: float
    refused: str = ""  # why the grader gave 0 whatever the tests said (vdtutorial.course.answer_rules), or ""
    failed: tuple[str, ...] = ()  # the trusted check's failures, in words (vdtutorial.course.checks)
    sandboxed: bool = True  # False: graded with --no-sandbox


def grade(
    paths,
    out="grades",
    source: Path | None = None,
    timeout: int = CELL_TIMEOUT,
    quick: bool = True,
    limits: Limits = Limits(),
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    log=None,
    static_check: bool = True,
) -> list[Score]:
    """Autograde submissions with nbgrader; returns one :class:`Score` per exercise and student.

    ``out`` becomes an nbgrader course directory (``source/``, ``submitted/``, ``autograded/``, the SQLite
    gradebook ``gradebook.db``) plus ``grades.csv``. Each submission runs on a fresh kernel bounded by
    ``limits``; a cell that raises or runs longer than ``timeout`` seconds scores 0 where it is a test and does
    not stop the others. ``quick`` runs the kernels in quick mode (small budgets: the exercises do not depend
    on them); their results go to ``runs/`` in each kernel's throwaway folder.

    The submissions are graded ``workers`` at a time, each in a course folder of its own (:func:`grade_one`) on
    ``backend`` (:func:`vdtutorial.runner.backends.run_jobs`: local processes, or Ray, ``address`` naming a
    cluster); this process alone writes their scores into the gradebook, so that it stays consistent however
    many run at once. ``log`` gets one line per graded submission. ``static_check=False`` skips
    :func:`refusals` (the points still come from the trusted checks alone). Each student's report goes to
    ``out/feedback/STUDENT/CHAPTER.md`` (:func:`vdtutorial.course.feedback.write_reports`).

    Each submission's result is kept in ``out/results`` as soon as its grading finished (:func:`_save_result`):
    run again on the same folder after an interruption, ``grade`` grades only the submissions without one, or
    whose notebook, chapter, mode or limits changed since, and writes the gradebook and ``grades.csv`` for all.
    """
    from vdtutorial.course.feedback import write_reports
    from vdtutorial.course.grading_process import run_each
    from vdtutorial.runner.backends import run_jobs

    _refuse_without_sandbox(limits)
    source = Path(source) if source is not None else notebooks_dir()
    out = Path(out).resolve()  # nbgrader's database URL and working directories need an absolute path
    subs = collect(paths, source)
    teachers = chapters(source)
    refused = [refusals(sub.path, teachers[sub.chapter]) if static_check else (None, {}) for sub in subs]
    for sub, (whole, _) in zip(subs, refused):
        if whole and log:
            log(f"refused {sub.student} {sub.chapter} without running it: {whole}")
    with tempfile.TemporaryDirectory(prefix="vdtutorial_grade_") as scratch, _quiet():
        api = _generate(out, source, sorted({s.chapter for s in subs}), timeout, sockets=Path(scratch), grading=True)
        gradebook = (out / "gradebook.db").read_bytes()
        marks = {k: _fingerprint(sub, out, quick, limits) for k, sub in enumerate(subs)}
        stored = {
            k: found
            for k, (whole, _) in enumerate(refused)
            if whole is None and (found := _stored_result(out, subs[k], marks[k])) is not None
        }
        if stored and log:
            log(f"resuming: {len(stored)} submissions were graded by an earlier run of this command, unchanged")
        run = [k for k, (whole, _) in enumerate(refused) if whole is None and k not in stored]
        jobs = [
            GradingJob(
                subs[k].student,
                subs[k].chapter,
                subs[k].path.read_bytes(),
                (out / "source" / ASSIGNMENT / f"{subs[k].chapter}.ipynb").read_bytes(),
                gradebook,
                timeout,
                quick,
                limits,
                secrets.randbits(63),
            )
            for k in run
        ]
        listener = _GradingLog(jobs, log, lambda i, result: _save_result(out, subs[run[i]], marks[run[i]], result))
        if backend == "local":
            done = run_each(jobs, workers, limits.wall_minutes * 60, did_not_finish, listener.finished)
        else:
            done = run_jobs(
                grade_one_supervised, jobs, workers=workers, backend=backend, address=address, listener=listener
            )
        graded = {**dict(zip(run, done)), **stored}
        results = [graded.get(k, Graded({}, None, None)) for k in range(len(subs))]
        for sub, result in zip(subs, results):
            for folder, data in (("submitted", sub.path.read_bytes()), ("autograded", result.autograded)):
                if data is not None:
                    dest = out / folder / sub.student / ASSIGNMENT / f"{sub.chapter}.ipynb"
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    dest.write_bytes(data)
            if result.error is not None:
                print(f"warning: nbgrader could not grade {sub.student}: {result.error}", file=sys.stderr)
            if result.unfinished is not None:
                print(
                    f"warning: the grading of {sub.student} {sub.chapter} did not finish: {result.unfinished}",
                    file=sys.stderr,
                )
        scores = _record(api, subs, results, refused, out, sandboxed=limits.sandbox)
    write_reports(scores, out, ASSIGNMENT)
    return scores


def _refuse_without_sandbox(limits: Limits) -> None:
    """A :class:`ClassroomError` naming the safe routes, where the kernels should be sandboxed and cannot be."""
    from vdtutorial.course import sandbox

    if limits.sandbox and (why := sandbox.available()) is not None:
        raise ClassroomError(
            f"no sandbox for the students' code ({why}): {sandbox.SAFE_ROUTES}; or pass "
            "--no-sandbox to run their code with your rights (the table then says so)"
        )


def refusals(path: Path, teacher: Path) -> tuple[str | None, dict[str, str]]:
    """What the static check (:func:`vdtutorial.course.answer_rules.answer_violations`) finds in the code of a
    submitted notebook that is the student's: its answer cells, and every other code cell that is not the
    teacher's chapter (``teacher``) as written (an added cell, or a chapter cell the student changed; nbgrader
    restores only the locked ones). Returns why the whole notebook scores 0 (tampering anywhere: it could change
    what every test does), or ``None``; and, per test cell, why that exercise scores 0 (the student's code uses
    the library's piece that the exercise rebuilds)."""
    import nbformat

    from vdtutorial.course.answer_rules import FORBIDDEN, answer_violations

    chapter = {
        cell.get("id"): cell.source for cell in nbformat.read(teacher, as_version=4).cells if cell.cell_type == "code"
    }
    every_name = tuple(sorted({name for names in FORBIDDEN.values() for name in names}))
    whole, each = [], {}
    for k, cell in enumerate(nbformat.read(path, as_version=4).cells):
        grading = cell.metadata.get("nbgrader", {})
        if cell.cell_type != "code" or grading.get("locked") or (grading.get("grade") and not grading.get("solution")):
            continue  # restored from the teacher's edition before it runs
        found = answer_violations(cell.source, FORBIDDEN.get(grading.get("grade_id"), every_name))
        if grading.get("solution"):
            where = grading["grade_id"]
        else:  # a chapter cell: only what the student's version adds to the teacher's counts
            where = f"cell {k + 1} (not an answer cell)"
            own = {(v.kind, v.text) for v in answer_violations(chapter.get(cell.get("id"), ""), every_name)}
            found = [v for v in found if (v.kind, v.text) not in own]
        for violation in found:
            why = f"{where} {violation}"
            if violation.kind == "tampering":
                whole.append(why)
                continue
            for exercise, forbidden in FORBIDDEN.items():
                if violation.name in forbidden and exercise == grading.get("grade_id", exercise):
                    each.setdefault(f"{exercise}_tests", why)
    return "; ".join(whole) or None, each


@dataclass(frozen=True)
class GradingJob:
    """One submission to grade, with everything its worker needs (a Ray node needs no shared folder): the
    notebook, the teacher's chapter and the gradebook that ``generate_assignment`` made of it, and the seed of
    the trusted checks' inputs (drawn afresh for every submission)."""

    student: str
    chapter: str
    submission: bytes
    teacher: bytes
    gradebook: bytes
    timeout: int
    quick: bool
    limits: Limits
    seed: int


@dataclass(frozen=True)
class Graded:
    """What :func:`grade_one` returns: ``failures``, each exercise's trusted-check failures in words (none: it
    passed), the autograded notebook, and ``error``: why nbgrader could not run the notebook to its end, or ``None``."""

    failures: dict
    autograded: bytes | None
    error: str | None
    unfinished: str | None = None  # why its grading process ended without a result (grading_process)


def did_not_finish(why: str) -> Graded:
    """The result of a submission whose grading process ended without one: no check passed, and why."""
    return Graded({}, None, None, unfinished=why)


def grade_one(job: GradingJob) -> Graded:
    """nbgrader's autograde of one submission, in a course folder of its own made in a throwaway folder, with each
    exercise's trusted check around it: the inputs drawn before the kernel starts and handed over as its tests
    cell runs (:class:`_Exchange`), the outputs judged after it stopped, here in the worker's process (the worker's
    part of :func:`grade`)."""
    import numpy as np

    from vdtutorial.course import checks

    with tempfile.TemporaryDirectory(prefix="vdtutorial_grade_") as scratch, _quiet():
        scratch = Path(scratch)
        course, exchange = scratch / "course", scratch / "checks"
        for folder, data in (("source", job.teacher), (f"submitted/{job.student}", job.submission)):
            (course / folder / ASSIGNMENT).mkdir(parents=True)
            (course / folder / ASSIGNMENT / f"{job.chapter}.ipynb").write_bytes(data)
        (course / "gradebook.db").write_bytes(job.gradebook)
        exchange.mkdir()
        (scratch / "sealed").mkdir()
        inputs = {}
        exercises = _exercises(course / "source" / ASSIGNMENT / f"{job.chapter}.ipynb")
        for k, exercise in enumerate(exercises):
            inputs[exercise] = checks.plain(checks.check(exercise).inputs(np.random.default_rng([job.seed, k])))
        turns = _Exchange(exchange, scratch / "sealed", inputs)
        kernel_env = {
            QUICK_ENV: "1" if job.quick else "0",
            "MPLBACKEND": "Agg",
            "PATH": _path_with_our_scripts(),
            "VDTUTORIAL_RUNS": "runs",
            checks.EXCHANGE_ENV: str(exchange),
            **_bounded_kernels(scratch, job.limits, writable=[exchange], exercises=exercises),
        }
        api = _api(course, job.timeout, sockets=scratch / "runtime", exchange=turns)
        with _environment(**kernel_env):
            result = api.autograde(ASSIGNMENT, job.student)
        turns.after()
        error = None if result["success"] else (result.get("error") or "").strip()[-300:]
        failures = {
            exercise: tuple(checks.judge(checks.check(exercise), given, turns.outputs(exercise)))
            for exercise, given in inputs.items()
        }
        autograded = course / "autograded" / job.student / ASSIGNMENT / f"{job.chapter}.ipynb"
        if autograded.is_file() and autograded.stat().st_size > MAX_NOTEBOOK_BYTES:  # outputs the kernel flooded
            return Graded(failures, None, f"the graded notebook is larger than {MAX_NOTEBOOK_BYTES >> 20} MB")
        return Graded(failures, autograded.read_bytes() if autograded.is_file() else None, error)


def grade_one_supervised(job: GradingJob) -> Graded:
    """:func:`grade_one` in a process of its own under the submission's wall-clock budget, as the local backend
    grades every submission (:func:`vdtutorial.course.grading_process.run_each`): a Ray task runs this, so that a
    killed, stopped or hung grading costs its submission alone on a cluster's node too, and the task ends within
    the budget."""
    from vdtutorial.course.grading_process import run_each

    return run_each([job], 1, job.limits.wall_minutes * 60, did_not_finish)[0]


def _exercises(chapter: Path) -> list[str]:
    """The exercises of a chapter notebook: the ``grade_id`` of each answer cell, in order."""
    return [g[: -len("_tests")] for g in grade_ids(chapter) if g.endswith("_tests")]


def _outputs(exchange: Path, exercise: str) -> dict | None:
    """What the kernel sent back for ``exercise``'s check, or ``None`` (nothing, or not a plain ``.npz`` whose
    arrays fit in :data:`~vdtutorial.course.checks.MAX_OUTPUTS_BYTES` once decompressed)."""
    from vdtutorial.course import checks

    path = checks.outputs_path(exchange, exercise)
    try:
        _check_npz_sizes(path, checks.MAX_OUTPUTS_BYTES)
        return checks.load(path)
    except Exception:  # missing, a link, too big, not an npz, or pickled objects: the kernel gave no usable answer
        return None


def _check_npz_sizes(path: Path, limit: int) -> None:
    """Raise ``ValueError`` unless the ``.npz`` at ``path`` holds only ``.npy`` members whose sizes, as the
    archive declares them and as each array's header declares its shape, add up to at most ``limit`` bytes:
    read before anything is decompressed (a few MB of zeros can declare gigabytes), and binding, since Python's
    ``zipfile`` stops a member at its declared size."""
    import zipfile

    import numpy as np

    if not path.is_file() or path.is_symlink() or path.stat().st_size > limit:
        raise ValueError(f"{path.name} is not a plain file of at most {limit} bytes")
    with zipfile.ZipFile(path) as archive:
        members = archive.infolist()
        if sum(m.file_size for m in members) > limit or not all(m.filename.endswith(".npy") for m in members):
            raise ValueError(f"{path.name} declares more than {limit} bytes, or holds more than arrays")
        for member in members:
            with archive.open(member) as fh:
                version = np.lib.format.read_magic(fh)
                shape, _, dtype = (
                    np.lib.format.read_array_header_1_0(fh)
                    if version == (1, 0)
                    else np.lib.format.read_array_header_2_0(fh)
                )
            if dtype.hasobject or int(np.prod(shape, dtype=object)) * dtype.itemsize > member.file_size:
                raise ValueError(f"{member.filename} declares more data than it holds, or objects")


#: The folder of a course (``--out``) that keeps each graded submission's result as it finishes
#: (:func:`_save_result`), so that a rerun after an interruption grades only the rest.
RESULTS = "results"


def _fingerprint(sub: Submission, out: Path, quick: bool, limits: Limits) -> str:
    """What a stored result was graded from: the submission's bytes, the chapter as graded (``out/source``), the
    mode and the limits; a result whose fingerprint differs is graded again."""
    import hashlib

    digest = hashlib.sha256()
    for part in (sub.path.read_bytes(), (out / "source" / ASSIGNMENT / f"{sub.chapter}.ipynb").read_bytes()):
        digest.update(hashlib.sha256(part).digest())
    digest.update(repr((quick, limits)).encode())
    return digest.hexdigest()


def _replace(path: Path, data: bytes) -> None:
    """``path`` holds ``data``, whole or not at all: written beside it, then renamed over it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    partial.write_bytes(data)
    os.replace(partial, path)


def _autograded_path(out: Path, sub: Submission) -> Path:
    return out / "autograded" / sub.student / ASSIGNMENT / f"{sub.chapter}.ipynb"


def _save_result(out: Path, sub: Submission, fingerprint: str, result: Graded) -> None:
    """Keep ``result`` of ``sub`` in ``out/results`` as soon as its grading finished (its autograded notebook first,
    then the record that names it: a record is never written before what it names)."""
    if result.autograded is not None:
        _replace(_autograded_path(out, sub), result.autograded)
    record = {
        "fingerprint": fingerprint,
        "failures": {exercise: list(failed) for exercise, failed in result.failures.items()},
        "error": result.error,
        "unfinished": result.unfinished,
        "autograded": result.autograded is not None,
    }
    _replace(out / RESULTS / sub.student / f"{sub.chapter}.json", json.dumps(record).encode())


def _stored_result(out: Path, sub: Submission, fingerprint: str) -> Graded | None:
    """The result :func:`_save_result` kept for ``sub``, if it was graded from the same ``fingerprint``."""
    try:
        record = json.loads((out / RESULTS / sub.student / f"{sub.chapter}.json").read_text())
        if record["fingerprint"] != fingerprint:
            return None
        autograded = _autograded_path(out, sub).read_bytes() if record["autograded"] else None
        failures = {exercise: tuple(failed) for exercise, failed in record["failures"].items()}
        return Graded(failures, autograded, record["error"], record["unfinished"])
    except (OSError, ValueError, KeyError, TypeError):  # none kept, or not whole: grade it again
        return None


class _GradingLog:
    """The listener of :func:`grade`'s jobs: ``keep(index, result)`` for each graded submission as it finishes,
    and one line for it to ``log`` (if any)."""

    def __init__(self, jobs: list[GradingJob], log, keep=None):
        self.jobs, self.log, self.keep, self.done = jobs, log, keep, 0

    def report(self, index, report) -> None:
        pass

    def tick(self) -> None:
        pass

    def finished(self, index, result: Graded) -> None:
        if self.keep is not None:
            self.keep(index, result)
        if self.log is None:
            return
        self.done += 1
        job = self.jobs[index]
        passed = sum(not failed for failed in result.failures.values())
        self.log(
            f"[{self.done}/{len(self.jobs)}] {job.student} {job.chapter}: {passed} of {len(result.failures)} "
            "exercises pass their checks" + ("" if result.error is None else " (the notebook stopped early)")
        )


def _record(
    api, subs: list[Submission], results: list[Graded], refused: list[tuple], out: Path, sandboxed: bool = True
) -> list[Score]:
    """Write every submission's points into the gradebook and into ``out/grades.csv``; returns them. An exercise
    scores its points when its trusted check passed and :func:`refusals` did not refuse it, else 0; the reason (the
    refusal, or the checks that failed) becomes the answer cell's comment, which nbgrader's formgrader shows. An
    answer that called a library stub (:mod:`vdtutorial.course.stubs`) is refused, with the stub's line as why."""
    from vdtutorial.course import checks

    scores = []
    with _environment(PATH=_path_with_our_scripts()), api.gradebook as gb:
        for sub, result, (whole, each) in zip(subs, results, refused):
            gb.update_or_create_student(sub.student)
            gb.update_or_create_submission(ASSIGNMENT, sub.student)
            for name in sorted(_test_cells(gb, sub.chapter)):
                exercise, top = name.removesuffix("_tests"), _max_points(gb, sub.chapter, name)
                why = (
                    whole
                    or each.get(name, "")
                    or (f"grading did not finish: {result.unfinished}" if result.unfinished else "")
                )
                failed = result.failures.get(exercise, ("the notebook was not run",))
                stub = next((line for text in failed if (line := checks.stubbed(text))), None)
                why = why or (f"{exercise} called a stub: {stub}" if stub else "")
                score = 0.0 if why or failed else top
                cell = gb.find_grade(name, sub.chapter, ASSIGNMENT, sub.student)
                cell.auto_score, cell.needs_manual_grade = score, False
                if why or failed:
                    with contextlib.suppress(Exception):  # an exercise whose answer cell has another name: no comment
                        comment = gb.find_comment(exercise, sub.chapter, ASSIGNMENT, sub.student)
                        comment.manual_comment = (
                            f"refused by the grader: {why}" if why else "hidden checks failed: " + "; ".join(failed)
                        )
                scores.append(Score(sub.student, sub.chapter, name, score, top, why, tuple(failed), sandboxed))
            gb.db.commit()
    write_csv(scores, out / "grades.csv")
    return scores


def _test_cells(gb, chapter: str) -> list[str]:
    return [c.name for c in gb.find_notebook(chapter, ASSIGNMENT).grade_cells]


def _max_points(gb, chapter: str, cell: str) -> float:
    return float(gb.find_grade_cell(cell, chapter, ASSIGNMENT).max_score)


def write_csv(scores: list[Score], path: Path) -> Path:
    """One row per student and exercise: student, chapter, exercise, score, max_score, refused (why the grader
    gave 0 whatever the tests said, or empty), sandbox (``yes``, or ``NO`` when graded with ``--no-sandbox``)."""
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["student", "chapter", "exercise", "score", "max_score", "refused", "sandbox"])
        for s in scores:
            writer.writerow(
                [s.student, s.chapter, s.exercise, s.score, s.max_score, s.refused, "yes" if s.sandboxed else "NO"]
            )
    return path


def table(scores: list[Score]) -> str:
    """Points per exercise (rows) and student (columns), with each student's total."""
    students = sorted({s.student for s in scores})
    rows = sorted({(s.chapter, s.exercise, s.max_score) for s in scores})
    got = {(s.student, s.chapter, s.exercise): f"{s.score:g}!" if s.refused else f"{s.score:g}" for s in scores}
    width = max([len(e) for _, e, _ in rows] + [8])
    lines = [f"{'exercise':<{width}} {'max':>5} " + " ".join(f"{st[:12]:>12}" for st in students)]
    for chapter, exercise, top in rows:
        cells = [got.get((st, chapter, exercise)) for st in students]
        lines.append(f"{exercise:<{width}} {top:5g} " + " ".join(f"{'-' if c is None else c:>12}" for c in cells))
    totals = [sum(s.score for s in scores if s.student == st) for st in students]
    possible = [sum(s.max_score for s in scores if s.student == st) for st in students]
    lines.append(f"{'total':<{width}} {'':>5} " + " ".join(f"{f'{t:g}/{p:g}':>12}" for t, p in zip(totals, possible)))
    if any(not s.sandboxed for s in scores):
        lines.insert(
            0,
            "graded WITHOUT a sandbox (--no-sandbox): the submissions' code ran with the grader's rights "
            "to files, network and processes, and could have changed these points\n",
        )
    reasons = sorted({(s.student, s.chapter, s.refused) for s in scores if s.refused})
    if reasons:
        lines.append("\n0! refused: the grader gave 0 whatever the tests said, because")
        lines += [f"  {student} {chapter}: {why}" for student, chapter, why in reasons]
    return "\n".join(lines)


def _cmd_release(args) -> None:
    written = release(args.out, Path(args.source), force=args.force)
    print(f"wrote the student edition of {len(written)} chapters to {Path(args.out)}/ (nbgrader generate_assignment)")


def _positive(name: str, value: float) -> None:
    """A limit must be a finite number above 0 (``inf``, ``nan`` and ``1e300`` CPU minutes included)."""
    if not (math.isfinite(value) and 0 < value <= _LARGEST[name]):
        raise ClassroomError(f"{name} must be a number above 0 and at most {_LARGEST[name]:g}, got {value:g}")


#: The largest value each option takes: past them a limit no longer fits the system's (64-bit) counters, or
#: means no limit at all.
_LARGEST = {
    "--memory": 2.0**33,
    "--cpu-minutes": 2.0**40,
    "--timeout": 2.0**31,
    "--workers": 4096,
    "--wall-minutes": 2.0**31,
}


def _cmd_grade(args) -> None:
    wall = args.wall_minutes
    if wall is None:
        wall = FULL_WALL_MINUTES if args.full else Limits.wall_minutes
    for name, value in (
        ("--memory", args.memory),
        ("--cpu-minutes", args.cpu_minutes),
        ("--timeout", args.timeout),
        ("--workers", args.workers),
        ("--wall-minutes", wall),
    ):
        _positive(name, value)
    if args.workers != int(args.workers):
        raise ClassroomError(f"--workers must be a whole number, got {args.workers:g}")
    limits = Limits(args.memory, args.cpu_minutes, sandbox=not args.no_sandbox, wall_minutes=wall)
    _refuse_without_sandbox(limits)
    print(
        f"each submission's kernel: at most {limits.memory_gb:g} GB of memory and {limits.cpu_minutes:g} CPU "
        "minutes, "
        + (
            "in a sandbox (bubblewrap): no network, no file of this machine but the Python environment, read-only"
            if limits.sandbox
            else f"NO SANDBOX: {SAFETY_NOTE}"
        ),
        file=sys.stderr,
    )
    if args.address is not None and args.backend == "local":
        raise ClassroomError("--address names a Ray cluster: use it with --backend ray")
    backend = args.backend or ("ray" if args.address is not None else "local")
    scores = grade(
        args.submissions,
        args.out,
        Path(args.source),
        math.ceil(args.timeout),
        quick=not args.full,
        limits=limits,
        workers=int(args.workers),
        backend=backend,
        address=args.address,
        log=lambda line: print(line, file=sys.stderr),
        static_check=not args.no_static_check,
    )
    print(table(scores))
    print(
        f"\ngradebook {Path(args.out) / 'gradebook.db'}, table {Path(args.out) / 'grades.csv'}, "
        f"each student's report {Path(args.out) / 'feedback'}/STUDENT/CHAPTER.md (no hidden check in it)"
    )


def _run(func):
    """Run a classroom command; a :class:`ClassroomError` becomes one line on stderr and exit code 2."""

    def wrapped(args):
        try:
            func(args)
        except ClassroomError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    return wrapped


def add_parser(subparsers) -> argparse.ArgumentParser:
    """The ``classroom`` command of ``python -m vdtutorial``: ``release OUT`` and ``grade SUBMISSIONS...``."""
    p = subparsers.add_parser("classroom", help="student edition and autograding with nbgrader")
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION", help="release or grade")
    r = sub.add_parser("release", help="write the student edition of every chapter (nbgrader generate_assignment)")
    r.add_argument("out", help="folder for the student notebooks")
    r.add_argument("--force", action="store_true", help="overwrite notebooks already in OUT")
    r.add_argument("--source", default=str(notebooks_dir()), help="the teacher's notebooks (default: %(default)s)")
    r.set_defaults(func=_run(_cmd_release))
    g = sub.add_parser(
        "grade",
        help="autograde submitted notebooks (nbgrader autograde + gradebook), print a table",
        description="Each SUBMISSION is STUDENT/NN_chapter.ipynb or a folder STUDENT/ of them. "
        "Each kernel is bounded: a memory and a CPU-time cap, a throwaway "
        "folder and, on Linux where user namespaces are allowed, no network and "
        "read-only files outside that folder.",
    )
    g.add_argument("submissions", nargs="+", help="STUDENT/NN_chapter.ipynb files or STUDENT/ folders")
    g.add_argument(
        "--out", default="grades", help="nbgrader course folder with gradebook.db and grades.csv (default: %(default)s)"
    )
    g.add_argument("--timeout", type=float, default=CELL_TIMEOUT, help="seconds per cell (default: %(default)s)")
    g.add_argument("--full", action="store_true", help="run the submissions with full budgets (default: quick mode)")
    g.add_argument(
        "--memory",
        type=float,
        default=Limits.memory_gb,
        metavar="GB",
        help="memory cap (GB) of each submission's kernel (default: %(default)s)",
    )
    g.add_argument(
        "--cpu-minutes",
        type=float,
        default=Limits.cpu_minutes,
        metavar="MIN",
        help="CPU-time cap of each submission's kernel; past it the kernel is killed (default: %(default)s)",
    )
    g.add_argument(
        "--wall-minutes",
        type=float,
        default=None,
        metavar="MIN",
        help="wall-clock budget of each submission's whole grading, past which it scores 0 "
        f"(default: {Limits.wall_minutes:g}, or {FULL_WALL_MINUTES:g} with --full)",
    )
    g.add_argument("--source", default=str(notebooks_dir()), help="the teacher's notebooks (default: %(default)s)")
    g.add_argument(
        "--workers",
        type=float,
        default=available_cores(),
        metavar="N",
        help="submissions graded at once, each on its own kernel (default: the cores available, %(default)s)",
    )
    g.add_argument(
        "--backend",
        choices=("local", "ray"),
        default=None,
        help="where the submissions are graded: local processes (default), or Ray, one task per "
        "submission (pip install -e '.[cluster]'); without --address Ray starts locally with --workers CPUs",
    )
    g.add_argument(
        "--address",
        default=None,
        help="join this Ray cluster (e.g. auto, or HEAD_IP:6379; implies --backend ray); its nodes need "
        "the same install (a submission travels with its job: no shared folder)",
    )
    g.add_argument(
        "--no-sandbox",
        action="store_true",
        help="where no sandbox can be made (no bubblewrap, no user namespaces): run the submissions' "
        "code with your rights to files, network and processes; the table says so",
    )
    g.add_argument(
        "--no-static-check",
        action="store_true",
        help="do not refuse answers for what their code reads like (answer_rules); the points still "
        "come from the trusted checks alone",
    )
    g.set_defaults(func=_run(_cmd_grade))
    return p
