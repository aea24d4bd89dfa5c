"""A grid of named jobs, run on a backend, restartable: the runner knows nothing of what a job computes.

A job (:class:`GridJob`) names itself, the file of its resumable state (:mod:`~vdtutorial.runner.resume`)
and of its rows, the settings its saved state must match, and how many rows and env steps it makes; its
``compute()`` yields progress reports, saves its state as it goes and returns its rows. Running the same
grid again continues it: finished jobs are not run again, partial ones resume from their last state, a
state saved with other settings is an error, never a silent mix. Each job holds a lock while it computes
(:mod:`~vdtutorial.runner.run_lock`), so grids sharing a state folder never compute a run twice; jobs go
to a backend (:mod:`~vdtutorial.runner.backends`: local processes or Ray), and the grid reports its
progress (:mod:`~vdtutorial.runner.progress`). The paper's runs are such jobs:
:mod:`vdtutorial.experiments.jobs`.

Taught in chapter 07.
"""

from __future__ import annotations

import os
import time
from collections.abc import Generator
from pathlib import Path
from typing import Protocol

from vdtutorial.runner.backends import run_jobs
from vdtutorial.runner.progress import GridProgress
from vdtutorial.runner.resume import ResumeError, check_resumable, read_run_state
from vdtutorial.runner.rows import stored_rows, write_csv
from vdtutorial.runner.run_lock import WAIT_S, RunLock, holder_alive, lock_path


class GridJob(Protocol):
    """What :func:`run_grid` needs of a job (it must pickle, to reach a worker process)."""

    name: str
    state_path: Path
    csv_path: Path
    settings: dict
    rows_expected: int
    env_steps: float

    def tags(self) -> dict: ...

    def summary(self, rows: list[dict]) -> str: ...

    def compute(self) -> Generator[dict, None, list[dict]]: ...


class SavedInStateDir:
    """A job's files in its grid's folder of states (``state_dir``), named after the job (``name``): its saved
    state and its rows. Mixed into a job that has both attributes."""

    @property
    def state_path(self) -> Path:
        return self.state_dir / f"{self.name}.pt"

    @property
    def csv_path(self) -> Path:
        return self.state_dir / f"{self.name}.csv"


def _result(
    job: GridJob, rows: list[dict], seconds: float, resumed_at: int | None = 0, stretches: list[dict] | None = None
) -> dict:
    """A job's rows labelled with its tags, its compute time, and a one-line summary. ``resumed_at``: the
    iteration this invocation continued it from (0: started now; None: found finished, its history is
    that of earlier invocations). ``stretches``: the numerics each stretch of the run was computed under, as its
    state keeps them (:func:`~vdtutorial.runner.resume.numerics_stretches`; None: a state that does not). The rows
    are rounded as a CSV stores them (:func:`~vdtutorial.runner.rows.stored_rows`)."""
    tags = job.tags()
    # rounded as the CSVs store them: an experiment derives what its shipped CSV gives back (runner.rows)
    return {
        "rows": stored_rows([{**tags, **row} for row in rows]),
        "seconds": seconds,
        "resumed_at": resumed_at,
        "stretches": stretches,
        "summary": job.summary(rows),
    }


def run_job(job: GridJob):
    """Execute (or continue) one job, as a job function of :func:`~vdtutorial.runner.backends.run_jobs`:
    yields the job's progress reports, writes its CSV at the end, and returns :func:`_result`. The job
    holds its lock (:class:`~vdtutorial.runner.run_lock.RunLock`) while it computes; if another process
    holds it, it waits and then continues from the state that process left (finished, usually)."""
    lock = RunLock(job.state_path)
    while not lock.acquire():  # another grid computes this job: wait for it, then take its result
        yield {"env_steps": 0}  # a report, so that a pool worker notices a killed grid while it waits
        time.sleep(WAIT_S)
    try:
        resumed_at = len(read_run_state(job.state_path)["rows"]) if job.state_path.exists() else 0
        rows = yield from job.compute()
    finally:
        lock.release()
    write_csv(job.csv_path, rows)
    state = read_run_state(job.state_path)
    return _result(job, rows, state["seconds"], resumed_at, state.get("numerics_stretches"))


def run_grid(
    name: str,
    jobs: list[GridJob],
    workers: int = 2,
    backend: str = "local",
    address: str | None = None,
    restart: bool = False,
    progress: bool | None = None,
) -> list[dict]:
    """Run ``jobs`` (see :func:`run_job`) and return their results in order; restartable.

    Before anything runs, each job's saved state is checked: a finished run is not run again (its saved
    rows are its result), a partial one resumes from its last state, and a state saved with other
    settings (or more iterations than asked for) stops the grid with a
    :class:`~vdtutorial.runner.resume.ResumeError` that names the file and the settings, unless
    ``restart`` discards the saved states of these jobs first. A run that another grid sharing the state
    folder is computing right now (its lock, :mod:`~vdtutorial.runner.run_lock`) is put last and
    waited for rather than computed twice. Progress: :class:`GridProgress`.
    """
    results: list[dict | None] = [None] * len(jobs)
    pending = []
    left = []
    partial = 0
    problems = []
    for i, job in enumerate(jobs):
        if restart:
            job.state_path.unlink(missing_ok=True)
            job.csv_path.unlink(missing_ok=True)
        if not job.state_path.exists():
            pending.append(i)
            left.append(job.env_steps)
            continue
        try:
            state = read_run_state(job.state_path)
            check_resumable(job.state_path, state, job.settings, job.rows_expected)
        except ResumeError as exc:
            problems.append(str(exc))
            continue
        if len(state["rows"]) == job.rows_expected:
            write_csv(job.csv_path, state["rows"])
            results[i] = _result(job, state["rows"], state["seconds"], None, state.get("numerics_stretches"))
        else:
            pending.append(i)
            left.append(job.env_steps * (1 - len(state["rows"]) / job.rows_expected))
            partial += 1
    if problems:
        others = f" (and {len(problems) - 1} more saved runs of this experiment)" if len(problems) > 1 else ""
        raise ResumeError(problems[0] + others)
    # runs that another grid is computing now go last: by the time a worker reaches them they may be finished
    busy = {i for i in pending if holder_alive(lock_path(jobs[i].state_path))}
    order = sorted(range(len(pending)), key=lambda k: pending[k] in busy)
    pending = [pending[k] for k in order]
    left = [left[k] for k in order]
    bar = GridProgress(name, [jobs[i].name for i in pending], left, len(jobs) - len(pending), len(jobs), progress)
    try:
        elsewhere = f", {len(busy)} of them being computed by another grid (waited for last)" if busy else ""
        states = Path(os.path.commonpath([job.state_path.parent for job in jobs]))
        bar.note(
            f"{len(jobs)} runs: {len(jobs) - len(pending)} found finished, {partial} to resume, "
            f"{len(pending) - partial} to start{elsewhere} (states saved in {states})"
        )
        for i, result in zip(pending, run_jobs(run_job, [jobs[i] for i in pending], workers, backend, address, bar)):
            results[i] = result
    finally:
        bar.close()
    return results
