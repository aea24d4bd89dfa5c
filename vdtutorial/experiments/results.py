"""An experiment's files: run a grid, then write the combined CSV, the figure and the JSON record."""
from __future__ import annotations

import json
import shlex
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure

import vdtutorial
from vdtutorial.experiments.curves import CONFIDENCE, SMOOTH_WINDOW, Curve, curves_from_rows, final_point
from vdtutorial.experiments.grid import Job, RunSpec, parallel_map, run_job
from vdtutorial.experiments.plots import plot_curves
from vdtutorial.experiments.rows import write_csv
from vdtutorial.experiments.runs import METRIC, NUM_ENVS, RUNS_DIR, default_trpo_config
from vdtutorial.pretrain import PretrainConfig, default_config
from vdtutorial.settings import DATA_DIR, QUICK, budget
from vdtutorial.trpo import TRPOConfig

@dataclass
class ExperimentResult:
    """What an experiment produced: its folder, all rows, the curves, the figure and a summary."""

    name: str
    out: Path
    rows: list[dict]
    curves: dict[str, Curve]
    figure: Figure
    summary: dict = field(default_factory=dict)


def experiment_command(name: str, **options) -> str:
    """The command line of an experiment (``python -m vdtutorial experiment NAME --option value ...``)."""
    parts = ["python", "-m", "vdtutorial", "experiment", name]
    for key, value in options.items():
        if value is None:
            continue
        flag = "--" + key.replace("_", "-")
        parts += [flag, *map(str, value)] if isinstance(value, (tuple, list)) else [flag, str(value)]
    return shlex.join(parts)


def default_out(name: str) -> Path:
    return Path(budget(DATA_DIR / "results" / name, RUNS_DIR / "quick" / name))


def run_experiment(name: str, specs: list[RunSpec], title: str, out: str | Path | None = None, workers: int = 2,
                   demos_root: Path | None = None, checkpoints_root: Path | None = None,
                   pretrain_config: PretrainConfig | None = None, trpo_config: TRPOConfig | None = None,
                   window: int = SMOOTH_WINDOW, command: str = "", summarise=None) -> ExperimentResult:
    """Run ``specs`` (in parallel), then write ``runs/RUN.csv`` per run, ``NAME.csv`` (all rows),
    ``NAME.png`` (:func:`plot_curves`) and ``NAME.json`` (command, configuration, per-run wall times,
    summary) into ``out``. The summary holds each curve's final point, plus whatever
    ``summarise(curves)`` returns. Defaults: ``out`` as in the module docstring; demonstrations from
    ``data/``; checkpoints in ``data/`` at full scale and in ``out`` in quick mode."""
    out = Path(out) if out is not None else default_out(name)
    checkpoints_root = checkpoints_root if checkpoints_root is not None else budget(None, out)
    trpo_config = trpo_config or default_trpo_config(specs[0].obs_mode)
    task = specs[0].task
    metric = METRIC[task]
    jobs = [Job(spec, out / "runs" / f"{spec.name}.csv", demos_root, checkpoints_root, pretrain_config,
                 trpo_config) for spec in specs]
    start = time.perf_counter()
    results = parallel_map(run_job, jobs, workers)
    wall = time.perf_counter() - start
    rows = [row for result in results for row in result["rows"]]
    write_csv(out / f"{name}.csv", rows)
    curves = curves_from_rows(rows, metric, window)
    figure = plot_curves(curves, metric, title, window)
    figure.savefig(out / f"{name}.png", dpi=120)
    summary = {"final": {label: final_point(curve) for label, curve in curves.items()},
               **(summarise(curves) if summarise else {})}
    record = {
        "experiment": name, "command": command, "argv": sys.argv, "quick": QUICK, "title": title,
        "metric": metric, "num_envs": NUM_ENVS, "steps_per_iteration": trpo_config.steps_per_iter,
        "window": window, "smoothing": f"trailing moving average over {window} iterations", "band": f"{CONFIDENCE:.0%} Student-t "
        "interval of the mean over seeds", "workers": workers, "wall_time_s": wall,
        "pretrain_config": {k: v for k, v in asdict(pretrain_config or default_config("vd", specs[0].obs_mode)).items()
                            if k not in ("reg", "obs_mode")},  # these two are set per run
        "trpo_config": asdict(trpo_config),
        "demos_root": str(demos_root or DATA_DIR), "checkpoints_root": str(checkpoints_root or DATA_DIR),
        "runs": [{**asdict(job.spec), "name": job.spec.name, "seconds": result["seconds"]}
                 for job, result in zip(jobs, results)],
        "summary": summary,
        "versions": {"vdtutorial": vdtutorial.__version__, "torch": torch.__version__, "gymnasium": gym.__version__,
                     "numpy": np.__version__, "python": sys.version.split()[0]},
    }
    (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=str))
    return ExperimentResult(name, out, rows, curves, figure, summary)

