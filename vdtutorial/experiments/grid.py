"""Many runs in parallel: a :class:`RunSpec` per curve and seed, executed on worker processes."""
from __future__ import annotations

import multiprocessing
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from vdtutorial.demos import demo_path
from vdtutorial.experiments.rows import write_csv
from vdtutorial.experiments.runs import METHODS, TOTAL_STEPS, expert_reference, finetune
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.trpo import TRPOConfig


@dataclass(frozen=True)
class RunSpec:
    """What one run is: a method, a data set (``samples``, ``noise``; None for "none" and "expert"), a
    seed. ``label`` names the curve it belongs to."""

    method: str
    task: str = "reach"
    samples: int | None = 8000
    noise: float | None = 0.5
    seed: int = 0
    obs_mode: str = "state"
    total_steps: int = TOTAL_STEPS
    label: str = ""

    def __post_init__(self):
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
    """A :class:`RunSpec` plus where its inputs and outputs live (what a worker process needs)."""

    spec: RunSpec
    csv_path: Path
    demos_root: Path | None
    checkpoints_root: Path | None
    pretrain_config: PretrainConfig | None
    trpo_config: TRPOConfig | None


def run_job(job: Job) -> dict:
    """Execute one run; returns its rows, each labelled with the spec, and its wall time."""
    spec, start = job.spec, time.perf_counter()
    if spec.method == "expert":
        rows = expert_reference(spec.task, spec.seed)
        write_csv(job.csv_path, rows)
    else:
        demos = (None if spec.method == "none"
                 else demo_path(spec.task, spec.samples, spec.noise, 0, root=job.demos_root))
        _, rows = finetune(spec.method, spec.task, demos, spec.obs_mode, spec.seed, spec.total_steps, job.csv_path,
                           pretrain_config=job.pretrain_config, trpo_config=job.trpo_config,
                           checkpoints_root=job.checkpoints_root)
    tags = {"label": spec.label, "method": spec.method, "task": spec.task, "samples": spec.samples,
            "noise": spec.noise, "obs_mode": spec.obs_mode, "seed": spec.seed}
    return {"rows": [{**tags, **row} for row in rows], "seconds": time.perf_counter() - start}


def _one_thread() -> None:
    torch.set_num_threads(1)


def parallel_map(fn, jobs: list, workers: int = 2) -> list:
    """``[fn(job) for job in jobs]`` on ``workers`` spawned processes, each with one torch thread; with
    ``workers=1`` in this process, also with one torch thread (restored afterwards), so that the
    results are the same either way. ``fn`` must be a module-level function."""
    if workers <= 1 or len(jobs) <= 1:
        threads = torch.get_num_threads()
        _one_thread()
        try:
            return [fn(job) for job in jobs]
        finally:
            torch.set_num_threads(threads)
    context = multiprocessing.get_context("spawn")
    with context.Pool(min(workers, len(jobs)), initializer=_one_thread) as pool:
        results = pool.map(fn, jobs, chunksize=1)
        pool.close()  # let the workers exit on their own: terminating them leaks their semaphores
        pool.join()
    return results

