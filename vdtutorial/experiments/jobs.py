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
from vdtutorial.experiments.runs import (
    CHECKPOINT_EVERY,
    METRIC,
    NUM_ENVS,
    default_expert_episodes,
    default_total_steps,
    expert_reference,
    expert_settings,
    finetune_steps,
    run_settings,
)
from vdtutorial.methods import method as method_entry
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner.resume import save_finished_rows
from vdtutorial.trpo import TRPOConfig


@dataclass(frozen=True)
class RunSpec:
    """What one run is: a method (:mod:`vdtutorial.methods`), a data set (``samples``, ``noise``; None for a method
    that does not pre-train), a
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
        if method_entry(self.method).pretrains and (self.samples is None or self.noise is None):
            raise ValueError(f"method {self.method!r} pre-trains: give the data set's samples and noise")

    @property
    def name(self) -> str:
        entry = method_entry(self.method)
        if not entry.finetuned:
            return f"{self.method}_{self.task}_seed{self.seed}"
        data = (
            ""
            if not entry.pretrains
            else f"_n{self.samples}_sigma{self.noise:g}" + (f"_demos{self.demo_seed}" if self.demo_seed else "")
        )
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
        entry = method_entry(spec.method)
        if not entry.finetuned:
            return expert_settings(spec.task, spec.seed, default_expert_episodes())
        config = self.pretrain_config or default_config(spec.method, spec.obs_mode)
        meta = {"samples": spec.samples, "noise": spec.noise, "seed": spec.demo_seed} if entry.pretrains else None
        return run_settings(spec.method, spec.task, meta, spec.obs_mode, spec.seed, NUM_ENVS, config, self.trpo_config)

    @property
    def rows_expected(self) -> int:
        """Log rows of the finished run: TRPO iterations, or the expert's episodes."""
        if not method_entry(self.spec.method).finetuned:
            return default_expert_episodes()
        return math.ceil(self.spec.total_steps / self.trpo_config.steps_per_iter)

    @property
    def env_steps(self) -> int:
        """Env steps of the finished run (the expert's: 200 per measured episode)."""
        finetuned = method_entry(self.spec.method).finetuned
        return self.rows_expected * (self.trpo_config.steps_per_iter if finetuned else EPISODE_STEPS)

    @property
    def name(self) -> str:
        return self.spec.name

    def tags(self) -> dict:
        """The columns that label each of the run's rows in an experiment's combined CSV."""
        spec = self.spec
        return {
            "label": spec.label,
            "method": spec.method,
            "task": spec.task,
            "samples": spec.samples,
            "noise": spec.noise,
            "obs_mode": spec.obs_mode,
            "seed": spec.seed,
        }

    def summary(self, rows: list[dict]) -> str:
        """A finished run in a few words: its last row's score."""
        metric = METRIC[self.spec.task]
        return f"{len(rows)} rows, last {metric} {rows[-1][metric]:.4g}"

    def compute(self):
        """Run (or continue) the run, saving its state as it goes: yields the progress reports of
        :func:`~vdtutorial.experiments.runs.finetune_steps` (the expert's reference: one at the end) and
        returns its rows."""
        spec = self.spec
        entry = method_entry(spec.method)
        if not entry.finetuned:
            start = time.perf_counter()
            rows = expert_reference(spec.task, spec.seed, default_expert_episodes())
            save_finished_rows(self.state_path, self.settings, rows, time.perf_counter() - start)
            yield {"env_steps": self.env_steps}
            return rows
        demos = (
            demo_path(spec.task, spec.samples, spec.noise, spec.demo_seed, root=self.demos_root)
            if (entry.pretrains)
            else None
        )
        _, rows = yield from finetune_steps(
            spec.method,
            spec.task,
            demos,
            spec.obs_mode,
            spec.seed,
            spec.total_steps,
            pretrain_config=self.pretrain_config,
            trpo_config=self.trpo_config,
            checkpoints_root=self.checkpoints_root,
            state_path=self.state_path,
            checkpoint_every=self.checkpoint_every,
            device=self.device,
        )
        return rows
