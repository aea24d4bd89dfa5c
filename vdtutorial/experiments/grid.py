"""A grid of runs: a :class:`RunSpec` per curve and seed, run on a backend, restartable.

Each run saves its state every few iterations (:mod:`~vdtutorial.experiments.resume`) in a state folder
(by default the experiment's ``runs/``; name another, e.g. on shared storage, for a cluster). Running the
same grid again continues it: finished runs are not run again, partial runs resume from their last
state, and the rows come out as those of an uninterrupted grid (wall times aside); a state saved with
other settings is an error, never a silent mix. Runs go to a backend
(:mod:`~vdtutorial.experiments.backends`: local processes or Ray), and the grid reports its progress
(:mod:`~vdtutorial.experiments.progress`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from vdtutorial.demos import demo_path
from vdtutorial.evaluation import EPISODE_STEPS
from vdtutorial.experiments.backends import run_jobs
from vdtutorial.experiments.progress import GridProgress
from vdtutorial.experiments.resume import ResumeError, check_resumable, read_run_state, save_finished_rows
from vdtutorial.experiments.rows import write_csv
from vdtutorial.experiments.run_lock import WAIT_S, RunLock, holder_alive, lock_path
from vdtutorial.experiments.runs import (CHECKPOINT_EVERY, METHODS, METRIC, NUM_ENVS, default_expert_episodes,
                                         default_total_steps, expert_reference, expert_settings, finetune_steps,
                                         run_settings)
from vdtutorial.pretrain import PretrainConfig, default_config
from vdtutorial.trpo import TRPOConfig


@dataclass(frozen=True)
class RunSpec:
    """What one run is: a method, a data set (``samples``, ``noise``; None for "none" and "expert"), a
    seed. ``label`` names the curve it belongs to. ``total_steps`` None: the RL budget of the mode the spec is
    made in (:func:`~vdtutorial.experiments.runs.default_total_steps`)."""

    method: str
    task: str = "reach"
    samples: int | None = 8000
    noise: float | None = 0.5
    seed: int = 0
    obs_mode: str = "state"
    total_steps: int | None = None
    label: str = ""

    def __post_init__(self):
        if self.total_steps is None:
            object.__setattr__(self, "total_steps", default_total_steps())  # frozen: set once, here
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.method in ("vd", "l2") and (self.samples is None or self.noise is None):
            raise ValueError(f"method {self.method!r} pre-trains: give the data set's samples and noise")

    @property
    def name(self) -> str:
        if self.method == "expert":
            return f"expert_{self.task}_seed{self.seed}"
        data = "" if self.method == "none" else f"_n{self.samples}_sigma{self.noise:g}"
        return f"{self.method}_{self.task}{data}_{self.obs_mode}_seed{self.seed}"


@dataclass(frozen=True)
class Job:
    """A :class:`RunSpec` plus where its inputs and outputs live (what a worker process needs).

    state_path: the run's resumable state (:mod:`~vdtutorial.experiments.resume`), saved every
        ``checkpoint_every`` iterations.
    csv_path: the run's rows, written when it has finished.
    """

    spec: RunSpec
    state_path: Path
    csv_path: Path
    demos_root: Path | None
    checkpoints_root: Path | None
    pretrain_config: PretrainConfig | None
    trpo_config: TRPOConfig
    checkpoint_every: int = CHECKPOINT_EVERY

    @property
    def settings(self) -> dict:
        """What the run's saved state must match (:func:`~vdtutorial.experiments.runs.run_settings`)."""
        spec = self.spec
        if spec.method == "expert":
            return expert_settings(spec.task, spec.seed, default_expert_episodes())
        config = self.pretrain_config or default_config(spec.method if spec.method != "none" else "l2", spec.obs_mode)
        meta = None if spec.method == "none" else {"samples": spec.samples, "noise": spec.noise, "seed": 0}
        return run_settings(spec.method, spec.task, meta, spec.obs_mode, spec.seed, NUM_ENVS, config, self.trpo_config)

    @property
    def rows_expected(self) -> int:
        """Log rows of the finished run: TRPO iterations, or the expert's episodes."""
        if self.spec.method == "expert":
            return default_expert_episodes()
        return math.ceil(self.spec.total_steps / self.trpo_config.steps_per_iter)

    @property
    def env_steps(self) -> int:
        """Env steps of the finished run (the expert's: 200 per measured episode)."""
        return self.rows_expected * (EPISODE_STEPS if self.spec.method == "expert" else self.trpo_config.steps_per_iter)


def _summary(spec: RunSpec, rows: list[dict]) -> str:
    """A finished run in a few words: its last row's score."""
    metric = METRIC[spec.task]
    return f"{len(rows)} rows, last {metric} {rows[-1][metric]:.4g}"


def _result(job: Job, rows: list[dict], seconds: float, resumed_at: int | None = 0) -> dict:
    """A run's rows labelled with its spec, its compute time, and a one-line summary. ``resumed_at``: the
    iteration this invocation continued it from (0: started now; None: found finished, its history is
    that of earlier invocations)."""
    spec = job.spec
    tags = {"label": spec.label, "method": spec.method, "task": spec.task, "samples": spec.samples,
            "noise": spec.noise, "obs_mode": spec.obs_mode, "seed": spec.seed}
    return {"rows": [{**tags, **row} for row in rows], "seconds": seconds, "resumed_at": resumed_at,
            "summary": _summary(spec, rows)}


def run_job(job: Job):
    """Execute (or continue) one run, as a job function of :func:`~vdtutorial.experiments.backends.run_jobs`:
    yields the progress reports of :func:`~vdtutorial.experiments.runs.finetune_steps`, saves the run's
    state as it goes, writes its CSV at the end, and returns :func:`_result`. A TRPO run holds its lock
    (:class:`~vdtutorial.experiments.run_lock.RunLock`) while it computes; if another process holds it,
    the job waits and then continues from the state that process left (finished, usually)."""
    spec, start = job.spec, time.perf_counter()
    if spec.method == "expert":
        rows = expert_reference(spec.task, spec.seed, default_expert_episodes())
        seconds = time.perf_counter() - start
        save_finished_rows(job.state_path, job.settings, rows, seconds)
        yield {"env_steps": job.env_steps}
        resumed_at = 0
    else:
        lock = RunLock(job.state_path)
        while not lock.acquire():  # another grid computes this run: wait for it, then take its result
            yield {"env_steps": 0}  # a report, so that a pool worker notices a killed grid while it waits
            time.sleep(WAIT_S)
        try:
            resumed_at = len(read_run_state(job.state_path)["rows"]) if job.state_path.exists() else 0
            demos = (None if spec.method == "none"
                     else demo_path(spec.task, spec.samples, spec.noise, 0, root=job.demos_root))
            _, rows = yield from finetune_steps(spec.method, spec.task, demos, spec.obs_mode, spec.seed,
                                                spec.total_steps, pretrain_config=job.pretrain_config,
                                                trpo_config=job.trpo_config, checkpoints_root=job.checkpoints_root,
                                                state_path=job.state_path, checkpoint_every=job.checkpoint_every)
        finally:
            lock.release()
        seconds = read_run_state(job.state_path)["seconds"]
    write_csv(job.csv_path, rows)
    return _result(job, rows, seconds, resumed_at)


def run_grid(name: str, jobs: list[Job], workers: int = 2, backend: str = "local", address: str | None = None,
             restart: bool = False, progress: bool | None = None) -> list[dict]:
    """Run ``jobs`` (see :func:`run_job`) and return their results in order; restartable.

    Before anything runs, each job's saved state is checked: a finished run is not run again (its saved
    rows are its result), a partial one resumes from its last state, and a state saved with other
    settings (or more iterations than asked for) stops the grid with a
    :class:`~vdtutorial.experiments.resume.ResumeError` that names the file and the settings, unless
    ``restart`` discards the saved states of these jobs first. A run that another grid sharing the state
    folder is computing right now (its lock, :mod:`~vdtutorial.experiments.run_lock`) is put last and
    waited for rather than computed twice. Progress: :class:`GridProgress`.
    """
    results: list[dict | None] = [None] * len(jobs)
    pending, left, partial, problems = [], [], 0, []
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
            results[i] = _result(job, state["rows"], state["seconds"], resumed_at=None)
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
    pending, left = [pending[k] for k in order], [left[k] for k in order]
    bar = GridProgress(name, [jobs[i].spec.name for i in pending], left, len(jobs) - len(pending), len(jobs), progress)
    try:
        elsewhere = f", {len(busy)} of them being computed by another grid (waited for last)" if busy else ""
        bar.note(f"{len(jobs)} runs: {len(jobs) - len(pending)} found finished, {partial} to resume, "
                 f"{len(pending) - partial} to start{elsewhere} (states saved in {jobs[0].state_path.parent})")
        for i, result in zip(pending, run_jobs(run_job, [jobs[i] for i in pending], workers, backend, address, bar)):
            results[i] = result
    finally:
        bar.close()
    return results
