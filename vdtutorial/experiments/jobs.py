"""The paper's runs as jobs of the grid runner: a :class:`RunSpec` (method, data set, seed) and the
:class:`Job` that computes it -- a TRPO fine-tuning run (:func:`~vdtutorial.experiments.runs.finetune_steps`)
or the IK expert's reference -- with the files the runner (:mod:`vdtutorial.runner.grid`) resumes and locks.

Taught in chapter 07.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from vdtutorial.demos import demo_path
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.evaluation import EPISODE_STEPS
from vdtutorial.experiments.runs import (CHECKPOINT_EVERY, METHODS, METRIC, NUM_ENVS, default_expert_episodes,
                                         default_total_steps, expert_reference, expert_settings, finetune_steps,
                                         run_settings)
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner.resume import save_finished_rows
from vdtutorial.trpo import TRPOConfig


@dataclass(frozen=True)
class RunSpec:
    """What one run is: a method, a data set (``samples``, ``noise``; None for "none" and "expert"), a
    seed. ``label`` names the curve it belongs to. ``total_steps`` None: the RL budget of the mode the spec is
    made in (:func:`~vdtutorial.experiments.runs.default_total_steps`). ``demo_seed``: which draw of the data set
    (the demonstrations' seed; the shipped sets are seed 0), named in the run's name when it is not 0."""

    method: str
    task: str = "reach"
    samples: int | None = 8000
    noise: float | None = 0.5
    seed: int = 0
    obs_mode: str = "state"
    total_steps: int | None = None
    label: str = ""
    demo_seed: int = 0

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
        data = "" if self.method == "none" else f"_n{self.samples}_sigma{self.noise:g}" + (
            f"_demos{self.demo_seed}" if self.demo_seed else "")
        return f"{self.method}_{self.task}{data}_{self.obs_mode}_seed{self.seed}"


@dataclass(frozen=True)
class Job:
    """A :class:`RunSpec` plus where its inputs and outputs live (what a worker process needs): a job of
    :func:`~vdtutorial.runner.grid.run_grid`.

    state_path: the run's resumable state (:mod:`~vdtutorial.runner.resume`), saved every
        ``checkpoint_every`` iterations.
    csv_path: the run's rows, written when it has finished.
    device: where TRPO's updates run (not one of the run's :attr:`settings`: see
        :func:`~vdtutorial.experiments.runs.finetune_steps`).
    """

    spec: RunSpec
    state_path: Path
    csv_path: Path
    demos_root: Path | None
    checkpoints_root: Path | None
    pretrain_config: PretrainConfig | None
    trpo_config: TRPOConfig
    checkpoint_every: int = CHECKPOINT_EVERY
    device: str = "cpu"

    @property
    def settings(self) -> dict:
        """What the run's saved state must match (:func:`~vdtutorial.experiments.runs.run_settings`)."""
        spec = self.spec
        if spec.method == "expert":
            return expert_settings(spec.task, spec.seed, default_expert_episodes())
        config = self.pretrain_config or default_config(spec.method if spec.method != "none" else "l2", spec.obs_mode)
        meta = None if spec.method == "none" else {"samples": spec.samples, "noise": spec.noise, "seed": spec.demo_seed}
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

    @property
    def name(self) -> str:
        return self.spec.name

    def tags(self) -> dict:
        """The columns that label each of the run's rows in an experiment's combined CSV."""
        spec = self.spec
        return {"label": spec.label, "method": spec.method, "task": spec.task, "samples": spec.samples,
                "noise": spec.noise, "obs_mode": spec.obs_mode, "seed": spec.seed}

    def summary(self, rows: list[dict]) -> str:
        """A finished run in a few words: its last row's score."""
        metric = METRIC[self.spec.task]
        return f"{len(rows)} rows, last {metric} {rows[-1][metric]:.4g}"

    def compute(self):
        """Run (or continue) the run, saving its state as it goes: yields the progress reports of
        :func:`~vdtutorial.experiments.runs.finetune_steps` (the expert's reference: one at the end) and
        returns its rows."""
        spec = self.spec
        if spec.method == "expert":
            start = time.perf_counter()
            rows = expert_reference(spec.task, spec.seed, default_expert_episodes())
            save_finished_rows(self.state_path, self.settings, rows, time.perf_counter() - start)
            yield {"env_steps": self.env_steps}
            return rows
        demos = None if spec.method == "none" else demo_path(spec.task, spec.samples, spec.noise, spec.demo_seed,
                                                                  root=self.demos_root)
        _, rows = yield from finetune_steps(spec.method, spec.task, demos, spec.obs_mode, spec.seed, spec.total_steps,
                                            pretrain_config=self.pretrain_config, trpo_config=self.trpo_config,
                                            checkpoints_root=self.checkpoints_root, state_path=self.state_path,
                                            checkpoint_every=self.checkpoint_every, device=self.device)
        return rows
