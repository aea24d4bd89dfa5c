"""An experiment's files: run a grid, then write the combined CSV, the figure and the JSON record."""
from __future__ import annotations

import json
import math
import os
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
from vdtutorial.experiments.curves import (CONFIDENCE, Curve, curves_from_rows, final_point, record_window,
                                           smooth_window)
from vdtutorial.experiments.effects import claim_effects
from vdtutorial.experiments.jobs import Job, RunSpec
from vdtutorial.runner.grid import run_grid
from vdtutorial.experiments.plots import plot_curves
from vdtutorial.runner.rows import read_rows, results_file, write_csv
from vdtutorial.kernels import kernel_settings
from vdtutorial.experiments.runs import CHECKPOINT_EVERY, METRIC, NUM_ENVS, RUNS_DIR, default_trpo_config
from vdtutorial.pretrain import PretrainConfig, default_config
from vdtutorial.settings import DATA_DIR, budget, is_quick, recorded_path
from vdtutorial.trpo import TRPOConfig

@dataclass
class ExperimentResult:
    """What an experiment produced: its folder, all rows, the curves, the figure and a summary."""

    name: str
    out: Path
    rows: list[dict]
    curves: dict[str, Curve]
    figure: Figure | None
    summary: dict = field(default_factory=dict)
    record: dict = field(default_factory=dict)

    @property
    def window(self) -> int:
        """The smoothing window of the curves (the record's, for a result read back)."""
        return record_window(self.record) if self.record else smooth_window()

    @property
    def metric(self) -> str:
        return self.record.get("metric", "successes")


def load_result(folder: str | Path, name: str | None = None) -> ExperimentResult | None:
    """Read back an experiment's folder (``NAME.csv.gz`` and ``NAME.json``; ``name`` defaults to the
    folder's name): rows, record, and the curves rebuilt with the record's smoothing window. None if
    either file is missing (the JSON is written last, so an experiment still running has none)."""
    folder = Path(folder)
    name = name or folder.name
    rows_path, record_path = results_file(folder, name), folder / f"{name}.json"
    if not (rows_path.exists() and record_path.exists()):
        return None
    record = json.loads(record_path.read_text())
    rows = read_rows(rows_path)
    curves = curves_from_rows(rows, record["metric"], record_window(record))
    return ExperimentResult(name, folder, rows, curves, None, record.get("summary", {}), record)


def experiment_command(name: str, **options) -> str:
    """The command line of an experiment (``python -m vdtutorial experiment NAME --option value ...``)."""
    parts = ["python", "-m", "vdtutorial", "experiment", name]
    for key, value in options.items():
        if value is None:
            continue
        flag = "--" + key.replace("_", "-")
        parts += [flag, *map(str, value)] if isinstance(value, (tuple, list)) else [flag, _recorded_argument(value)]
    return shlex.join(parts)


def _recorded_argument(value) -> str:
    """A command-line argument as a shipped record writes it: a path relative to the folder holding data/."""
    return recorded_path(value) if isinstance(value, Path) or os.path.isabs(str(value)) else str(value)


def recorded_argv() -> list[str]:
    """This process's command line as a record writes it: ``python -m vdtutorial ...`` rather than the path of
    the package's ``__main__.py``, and paths relative to the folder holding data/ (see ``recorded_path``)."""
    program = sys.argv[0]
    head = (["python", "-m", "vdtutorial"] if Path(program).name == "__main__.py"
            and Path(program).resolve().parent == Path(vdtutorial.__file__).resolve().parent else [Path(program).name])
    return head + [_recorded_argument(arg) for arg in sys.argv[1:]]


def default_out(name: str) -> Path:
    """``runs/NAME`` beside ``data/`` (quick mode: ``runs/quick/NAME``). Shipped results in ``data/results``
    are only replaced by naming them with ``out``."""
    return Path(budget(RUNS_DIR / name, RUNS_DIR / "quick" / name))


def run_experiment(name: str, specs: list[RunSpec], title: str, out: str | Path | None = None, workers: int = 2,
                   demos_root: Path | None = None, checkpoints_root: Path | None = None,
                   pretrain_config: PretrainConfig | None = None, trpo_config: TRPOConfig | None = None,
                   window: int | None = None, command: str = "", summarise=None, *, backend: str = "local",
                   address: str | None = None, state_dir: str | Path | None = None, restart: bool = False,
                   checkpoint_every: int = CHECKPOINT_EVERY, progress: bool | None = None) -> ExperimentResult:
    """Run ``specs`` as a restartable grid (:func:`~vdtutorial.runner.grid.run_grid`), then write
    ``NAME.csv.gz`` (all rows), ``NAME.png`` (:func:`plot_curves`) and ``NAME.json`` (command, configuration,
    per-run compute times, summary) into ``out``. The summary holds each curve's final point, plus
    whatever ``summarise(curves)`` returns.

    out: default :func:`default_out`.
    window: the curves' smoothing, in iterations (default
        :func:`~vdtutorial.experiments.curves.smooth_window`).
    demos_root: where the demonstrations are read (default ``data/``).
    checkpoints_root: where pre-trained checkpoints are made when the shipped ones do not match
        (default ``out``; see :func:`~vdtutorial.experiments.runs.pretrained_policy`).
    backend, address, workers: where the runs execute (:mod:`~vdtutorial.runner.backends`).
    state_dir: the runs' saved states and CSVs (default ``out/runs``; on a cluster, shared storage).
    restart: discard the saved states of these runs instead of continuing them.
    checkpoint_every: TRPO iterations between two saved states of a run.
    progress: the grid's live line and per-run lines (:mod:`~vdtutorial.runner.progress`).
    """
    out = Path(out) if out is not None else default_out(name)
    window = smooth_window() if window is None else window
    state_dir = Path(state_dir) if state_dir is not None else out / "runs"
    # absolute paths: a worker (a Ray task on another node, say) may start elsewhere
    demos_root = Path(demos_root or DATA_DIR).resolve()
    checkpoints_root = Path(checkpoints_root if checkpoints_root is not None else out).resolve()
    trpo_config = trpo_config or default_trpo_config(specs[0].obs_mode)
    task = specs[0].task
    metric = METRIC[task]
    jobs = [Job(spec, state_dir.resolve() / f"{spec.name}.pt", state_dir.resolve() / f"{spec.name}.csv", demos_root,
                checkpoints_root, pretrain_config, trpo_config, checkpoint_every) for spec in specs]
    start = time.perf_counter()
    results = run_grid(name, jobs, workers, backend, address, restart, progress)
    wall = time.perf_counter() - start
    rows = [row for result in results for row in result["rows"]]
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results_file(out, name), rows)
    curves = curves_from_rows(rows, metric, window)
    figure = plot_curves(curves, metric, title, window)
    figure.savefig(out / f"{name}.png", dpi=120)
    summary = {"final": {label: final_point(curve) for label, curve in curves.items()},
               "claims": claim_effects(name, rows, metric, window),
               **(summarise(curves) if summarise else {})}
    record = {
        "experiment": name, "command": command, "argv": recorded_argv(), "quick": is_quick(), "title": title,
        "metric": metric, "num_envs": NUM_ENVS, "steps_per_iteration": trpo_config.steps_per_iter,
        "window": window, "smoothing": f"trailing moving average over {window} iterations", "band": f"{CONFIDENCE:.0%} Student-t "
        "interval of the mean over seeds", "workers": workers, "backend": backend, "wall_time_s": wall,
        "pretrain_config": {k: v for k, v in asdict(pretrain_config or default_config("vd", specs[0].obs_mode)).items()
                            if k not in ("reg", "obs_mode")},  # these two are set per run
        "trpo_config": asdict(trpo_config),
        # folders as the commands name them: relative to the folder that holds data/
        "demos_root": recorded_path(demos_root), "checkpoints_root": recorded_path(checkpoints_root),
        "state_dir": recorded_path(state_dir),
        "runs": [{**asdict(job.spec), "name": job.spec.name, "seconds": result["seconds"],
                  # the iteration this command continued the run from; null: found finished
                  "resumed_at_iteration": result["resumed_at"]} for job, result in zip(jobs, results)],
        "summary": summary,
        "versions": {"vdtutorial": vdtutorial.__version__, "torch": torch.__version__, "gymnasium": gym.__version__,
                     "numpy": np.__version__, "python": sys.version.split()[0]},
        "kernels": kernel_settings(),  # the CPU vector kernels in use (vdtutorial.kernels)
    }
    (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=str))
    return ExperimentResult(name, out, rows, curves, figure, summary, record)


def format_summary(result: ExperimentResult) -> str:
    """The final level of every curve with its band (or, with one seed, the words that there is none),
    the fig4-style "VD reaches L2" line if any, and where the files went."""
    lines = []
    for label, final in result.summary["final"].items():
        seeds = f"{final['seeds']} seed{'s' if final['seeds'] != 1 else ''}"
        if math.isfinite(final["low"]):
            band = f"{CONFIDENCE:.0%} band {final['low']:.2f} to {final['high']:.2f}, {seeds}"
        else:
            band = f"{seeds}: no band from a single sample"
        lines.append(f"{label:>32}: final {final['mean']:.2f} ({band})")
    if "vd_reaches_l2_final" in result.summary:
        lines.append(result.summary["vd_reaches_l2_final"]["text"])
    lines.append(f"wrote {result.out}")
    return "\n".join(lines)
