"""Each submission graded in a process of its own, so that one student never stops the class.

A submission's kernel runs in a sandbox, but the process that drives it (nbgrader's autograde, the kernel's client)
is the grader's: if that process is killed, stopped, hangs or crashes, a pool of workers sharing it would lose or
wait for every submission queued behind it. :func:`run_each` therefore starts one process per submission, in a
session (and process group) of its own, at most ``workers`` at a time, and gives each a wall-clock budget
measured from outside. A process that ends without a result, or is still running when its budget is spent, is
killed with its whole process group (the kernel's sandbox goes with it: bubblewrap ends the sandbox when its
parent dies) and costs that submission alone: its result says ``grading did not finish: ...``, and every other
submission is graded as usual. Each process is told this supervisor's pid, and ends itself with its group if the
supervisor dies (:func:`vdtutorial.course.grading_worker.end_with`).

The job and its result travel as files in a folder that only the grading processes can read (never a sandbox's).

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: How often the supervisor looks at its processes (seconds).
POLL_SECONDS = 0.5


def _why(returncode: int | None, budget: float) -> str:
    if returncode is None:
        return f"it was still running after its budget of {budget / 60:g} minutes (hung or stopped)"
    if returncode < 0:
        return f"the grading process was killed by {signal.Signals(-returncode).name}"
    return f"the grading process exited with code {returncode} and no result"


def _kill(process: subprocess.Popen) -> None:
    """The process and every process of its group, at once (a stopped one included: SIGKILL needs no waking)."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait()


def run_each(
    jobs: list,
    workers: int,
    budget_seconds: float,
    did_not_finish,
    finished=None,
    worker: str = "vdtutorial.course.grading_worker",
) -> list:
    """The module ``worker`` run (``python -m``) on every job, each in its own process and session, ``workers`` at
    a time; returns the results in the order of the jobs, ``did_not_finish(why)`` for a job whose process ended
    without one. ``finished(index, result)`` is called as each one ends. The worker is named, not imported, so this
    supervisor knows nothing of what a job is."""
    results: list = [None] * len(jobs)
    with tempfile.TemporaryDirectory(prefix="vdtutorial_grading_") as folder:
        folder = Path(folder)
        waiting, running = list(range(len(jobs))), {}
        try:
            callbacks = (worker, did_not_finish, finished)
            _supervise(jobs, workers, budget_seconds, callbacks, folder, waiting, running, results)
        finally:  # interrupted (Ctrl-C): no grading process outlives the grader
            for process, _ in running.values():
                _kill(process)
    return results


def _supervise(jobs, workers, budget_seconds, callbacks, folder, waiting, running, results) -> None:
    """:func:`run_each`'s loop: start processes while there is room, collect or kill those that are done or out
    of budget (``waiting``, ``running`` and ``results`` are updated in place, for the caller's clean-up)."""
    worker, did_not_finish, finished = callbacks
    while waiting or running:
        while waiting and len(running) < workers:
            k = waiting.pop(0)
            (folder / f"{k}.job").write_bytes(pickle.dumps(jobs[k]))
            process = subprocess.Popen(
                [sys.executable, "-m", worker, str(folder / f"{k}.job"), str(folder / f"{k}.result"), str(os.getpid())],
                start_new_session=True,
                stdin=subprocess.DEVNULL,
            )
            running[k] = (process, time.monotonic())
        time.sleep(POLL_SECONDS)
        for k, (process, start) in list(running.items()):
            returncode = process.poll()
            over = returncode is None and time.monotonic() - start > budget_seconds
            if returncode is None and not over:
                continue
            _kill(process)
            result_file = folder / f"{k}.result"
            if returncode == 0 and result_file.is_file():
                results[k] = pickle.loads(result_file.read_bytes())
            else:
                results[k] = did_not_finish(_why(None if over else returncode, budget_seconds))
            del running[k]
            if finished is not None:
                finished(k, results[k])
