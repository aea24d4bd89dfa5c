"""An experiment's files: run a grid, then write the combined CSV, the figure and the JSON record. Taught in chapter
07."""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure

import vdtutorial
from vdtutorial.experiments.batches import mark_batches
from vdtutorial.experiments.checkpoints import current_field_names, default_config
from vdtutorial.experiments.curves import (
    CONFIDENCE,
    Curve,
    curves_from_rows,
    final_point,
    record_window,
    smooth_window,
    vd_reaches_l2_final,
)
from vdtutorial.experiments.effects import claim_effects
from vdtutorial.experiments.jobs import Job, RunSpec
from vdtutorial.experiments.looks import looks_of
from vdtutorial.experiments.plans import plan_entry, plan_named, primary_of
from vdtutorial.experiments.measures import measures_of
from vdtutorial.experiments.plots import band_limits, figure_title, plot_measures, save_png
from vdtutorial.experiments.runs import CHECKPOINT_EVERY, METRIC, NUM_ENVS, default_trpo_config
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner.grid import run_grid
from vdtutorial.runner.kernels import kernel_settings
from vdtutorial.runner.rows import read_rows, results_file, write_csv
from vdtutorial.experiments.paths import recorded_path, runs_dir
from vdtutorial.settings import budget, data_dir, is_quick
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
    head = (
        ["python", "-m", "vdtutorial"]
        if Path(program).name == "__main__.py"
        and Path(program).resolve().parent == Path(vdtutorial.__file__).resolve().parent
        else [Path(program).name]
    )
    return head + [_recorded_argument(arg) for arg in sys.argv[1:]]


def default_out(name: str) -> Path:
    """``runs/NAME`` beside ``data/`` (quick mode: ``runs/quick/NAME``). Shipped results in ``data/results``
    are only replaced by naming them with ``out``."""
    return Path(budget(runs_dir() / name, runs_dir() / "quick" / name))


def run_experiment(
    name: str,
    specs: list[RunSpec],
    title: str,
    out: str | Path | None = None,
    workers: int = 2,
    demos_root: Path | None = None,
    checkpoints_root: Path | None = None,
    pretrain_config: PretrainConfig | None = None,
    trpo_config: TRPOConfig | None = None,
    window: int | None = None,
    command: str = "",
    summarise=None,
    *,
    backend: str = "local",
    address: str | None = None,
    state_dir: str | Path | None = None,
    restart: bool = False,
    checkpoint_every: int = CHECKPOINT_EVERY,
    progress: bool | None = None,
    device: str = "cpu",
) -> ExperimentResult:
    """Run ``specs`` as a restartable grid (:func:`~vdtutorial.runner.grid.run_grid`), then write
    ``NAME.csv.gz`` (all rows), ``NAME.png`` (:func:`derive`: one panel per measure) and ``NAME.json``
    (command, configuration, per-run compute times, summary) into ``out``. The summary holds each curve's
    final point on every measure and the claims (:func:`derive`), plus whatever ``summarise(curves)`` returns.
    ``title``: the paper's figure; the observation, budget, seeds and a control are added to it
    (:func:`~vdtutorial.experiments.plots.figure_title`).

    out: default :func:`default_out`.
    window: the curves' smoothing, in iterations (default
        :func:`~vdtutorial.experiments.curves.smooth_window`).
    demos_root: where the demonstrations are read (default ``data/``).
    checkpoints_root: where pre-trained checkpoints are made when the shipped ones do not match
        (default ``out``; see :func:`~vdtutorial.experiments.pipeline.pretrained_policy`).
    backend, address, workers: where the runs execute (:mod:`~vdtutorial.runner.backends`).
    state_dir: the runs' saved states and CSVs (default ``out/runs``; on a cluster, shared storage).
    restart: discard the saved states of these runs instead of continuing them.
    checkpoint_every: TRPO iterations between two saved states of a run.
    progress: the grid's live line and per-run lines (:mod:`~vdtutorial.runner.progress`).
    device: where the runs' TRPO updates run ("cuda": a GPU; see :func:`~vdtutorial.experiments.runs.finetune_steps`).
    """
    out = Path(out) if out is not None else default_out(name)
    window = smooth_window() if window is None else window
    state_dir = Path(state_dir) if state_dir is not None else out / "runs"
    # absolute paths: a worker (a Ray task on another node, say) may start elsewhere
    demos_root = Path(demos_root or data_dir()).resolve()
    checkpoints_root = Path(checkpoints_root if checkpoints_root is not None else out).resolve()
    trpo_config = trpo_config or default_trpo_config()
    task = specs[0].task
    metric = METRIC[task]
    jobs = [
        Job(
            spec,
            state_dir.resolve() / f"{spec.name}.pt",
            state_dir.resolve() / f"{spec.name}.csv",
            demos_root,
            checkpoints_root,
            pretrain_config,
            trpo_config,
            checkpoint_every,
            device,
        )
        for spec in specs
    ]
    start = time.perf_counter()
    results = run_grid(name, jobs, workers, backend, address, restart, progress)
    wall = time.perf_counter() - start
    rows = [row for result in results for row in result["rows"]]
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results_file(out, name), rows)
    title = figure_title(
        title,
        specs[0].obs_mode,
        specs[0].total_steps,
        len({spec.seed for spec in specs}),
        trpo_config.fvp_subsample,
        max(spec.demo_seed for spec in specs),
    )
    curves, figure, summary = derive(name, rows, metric, window, title)
    save_png(figure, out / f"{name}.png", 120)
    summary.update(summarise(curves) if summarise else {})
    record = {
        "experiment": name,
        "command": command,
        "argv": recorded_argv(),
        "quick": is_quick(),
        "title": title,
        "metric": metric,
        "measures": list(measures_of(metric)),
        "seeds": sorted({spec.seed for spec in specs}),
        "num_envs": NUM_ENVS,
        "steps_per_iteration": trpo_config.steps_per_iter,
        "window": window,
        "smoothing": f"trailing moving average over {window} iterations",
        "band": f"{CONFIDENCE:.0%} Student-t interval of the mean over seeds",
        "workers": workers,
        "backend": backend,
        "wall_time_s": wall,
        "device": device,  # where the TRPO updates ran: a GPU's rows differ from the CPU's by rounding
        "pretrain_config": {
            k: v
            for k, v in asdict(pretrain_config or default_config("vd", specs[0].obs_mode)).items()
            if k not in ("reg", "obs_mode")
        },  # these two are set per run
        "trpo_config": asdict(trpo_config),
        # folders as the commands name them: relative to the folder that holds data/
        "demos_root": recorded_path(demos_root),
        "checkpoints_root": recorded_path(checkpoints_root),
        "state_dir": recorded_path(state_dir),
        "runs": [
            {
                **asdict(job.spec),
                "name": job.spec.name,
                "seconds": result["seconds"],
                # the iteration this command continued the run from; null: found finished
                "resumed_at_iteration": result["resumed_at"],
                # the numerics (versions, kernels, CPU) of each stretch of the run; null: its state kept none
                "numerics_stretches": result.get("stretches"),
            }
            for job, result in zip(jobs, results)
        ],
        "summary": summary,
        "versions": {
            "vdtutorial": vdtutorial.__version__,
            "torch": torch.__version__,
            "gymnasium": gym.__version__,
            "numpy": np.__version__,
            "python": sys.version.split()[0],
        },
        "kernels": kernel_settings(),  # the CPU vector kernels in use (vdtutorial.runner.kernels)
    }
    (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=str))
    return ExperimentResult(name, out, rows, curves, figure, summary, record)


def derive(
    name: str, rows: list[dict], metric: str, window: int, title: str, claims=None, looks=None, primary=None
) -> tuple[dict[str, Curve], Figure, dict]:
    """What an experiment's rows say, all of it re-derivable from them: the curves of the paper's ``metric``,
    the figure (one panel per measure, :func:`~vdtutorial.experiments.measures.measures_of`), and the summary:
    each curve's final point on the paper's metric (``final``) and on every measure (``final_by_measure``),
    and the claims on every measure (:func:`~vdtutorial.experiments.effects.claim_effects`; ``claims``: other
    claims than the experiment's own; ``looks``: the seeds each look added, for an experiment extended after its
    result was seen, :mod:`~vdtutorial.experiments.looks`; ``primary``: the claims a pre-registered plan decides on,
    :mod:`~vdtutorial.experiments.plans`)."""
    by_measure = {measure: curves_from_rows(rows, measure, window) for measure in measures_of(metric)}
    summary = {
        "final": {label: final_point(curve) for label, curve in by_measure[metric].items()},
        "final_by_measure": {
            measure: {label: final_point(curve) for label, curve in curves.items()}
            for measure, curves in by_measure.items()
        },
        "claims": claim_effects(name, rows, metric, window, claims=claims, looks=looks, primary=primary),
    }
    return by_measure[metric], plot_measures(by_measure, title, window), summary


def rederive(folder: str | Path, plan: str | None = None) -> ExperimentResult:
    """Re-write an experiment folder's figure and the derived part of its JSON record (:func:`derive`; and
    the "VD reaches L2's final level" summary where the record has one) from its rows, without running
    anything: what ``python -m vdtutorial rederive FOLDER`` does after the analysis changed. The title is
    rebuilt from the record (its first line is the paper's figure; observation, budget, seeds and control are
    read from the runs and the TRPO configuration).

    ``plan``: the name of the pre-registered plan the folder's runs were made under
    (:data:`~vdtutorial.experiments.plans.PLANS`), written into the record; a record with a plan is tested by it
    on every re-derivation, and refused (ValueError, nothing written) once its runs are no longer the plan's."""
    folder = Path(folder)
    record_path = next(folder.glob("*.json"))
    record = json.loads(record_path.read_text())
    if plan is not None:
        record["plan"] = plan_entry(plan_named(plan), record)
    elif record.get("plan"):
        plan_entry(plan_named(record["plan"]["name"]), record)
    name, window = record["experiment"], record_window(record)
    rows = read_rows(results_file(folder, name))
    learners = [run for run in record["runs"] if run["method"] != "expert"]
    seeds = sorted({row["seed"] for row in rows})
    counts = sorted({sum(r["label"] == run["label"] for r in record["runs"]) for run in record["runs"]})
    title = figure_title(
        record["title"].split("\n")[0],
        learners[0]["obs_mode"],
        max(run["total_steps"] for run in learners),
        len(seeds) if len(counts) == 1 else f"{counts[0]} to {counts[-1]}",
        record["trpo_config"].get("fvp_subsample", 1.0),
        max(run.get("demo_seed", 0) for run in learners),
    )
    curves, figure, derived = derive(
        name, rows, record["metric"], window, title, looks=looks_of(record), primary=primary_of(record)
    )
    save_png(figure, folder / f"{name}.png", 120)
    summary = {**record.get("summary", {}), **derived}
    summary["claims"] = mark_batches(summary["claims"], record, rows)  # a merged record: claims crossing batches
    if "vd_reaches_l2_final" in summary:
        summary["vd_reaches_l2_final"] = vd_reaches_l2_final(curves)
    record.update(title=title, measures=list(measures_of(record["metric"])), seeds=seeds, summary=summary)
    record_path.write_text(json.dumps(record, indent=1, default=str))
    return ExperimentResult(name, folder, rows, curves, figure, summary, record)


#: A merged part's kernels when its record predates the ``kernels`` entry (runner.kernels): unknown, not the default.
NOT_RECORDED = "not recorded (the run predates the record's kernels entry)"
#: What two records must agree on for their rows to be one experiment's (everything that shapes a run but its seed).
SAME_EXPERIMENT = (
    "experiment",
    "metric",
    "num_envs",
    "steps_per_iteration",
    "window",
    "pretrain_config",
    "trpo_config",
    "quick",
    "versions",
    "kernels",
)
#: The settings a record holds as a dataclass's fields. A field added since a record was written is absent from
#: it; a new field's default is what the code did before the field existed (``PretrainConfig.patience``: None,
#: no early stop), so a missing field is read as its default.
CONFIGS = {"pretrain_config": PretrainConfig, "trpo_config": TRPOConfig}


def with_defaults(key: str, value, names) -> dict:
    """``value`` of a record's ``key`` with those of the fields ``names`` that it predates filled in with their
    defaults (:data:`CONFIGS`); other keys as they are."""
    if key not in CONFIGS or not isinstance(value, dict):
        return value
    names = current_field_names(dict.fromkeys(names))
    return {
        **{f.name: f.default for f in fields(CONFIGS[key]) if f.name in names and f.default is not MISSING},
        **current_field_names(value),
    }


def _names(records: list[dict], key: str) -> set:
    """The field names either record holds under ``key``."""
    return {name for record in records if isinstance(record.get(key), dict) for name in record[key]}


def merge_seeds(folder: str | Path, other: str | Path, other_cpu: bool = False) -> ExperimentResult:
    """Add the runs of ``other`` (the same experiment run with other seeds) to the experiment in ``folder``, then
    :func:`rederive` it: what ``python -m vdtutorial rederive FOLDER --add OTHER`` does. A run is a pure function
    of its settings and seed (docs/results.md, "Regenerable results"), so the merged rows are those one command
    with all the seeds would write on a CPU that rounds alike, in its order (each curve's runs by seed), the
    ``wall_time`` column aside; the
    record's ``command`` is that one command (never run as such; when the parts ran different curves, e.g. more seeds
    of one data set, no single command makes the rows and the first part's command stays), and ``merged`` lists, in
    order, each command that ran with its seeds and kernels, then each merge (this function's own command line).
    Refuses records that differ
    in anything but the seeds (:data:`SAME_EXPERIMENT`, and the runs' budgets and observations) or that both hold a
    curve's seed; ``other`` may hold only some of the methods (more seeds of the curves that need them, e.g. the
    image Fig. 4's no pre-training at seeds 3-9, run after VD's and L2's).

    ``other_cpu``: also merge seeds run with other CPU kernels (a ``kernels`` entry that differs, or that one
    record predates). Each seed stays a valid replicate -- kernels change the last bits, which TRPO amplifies,
    not what a run computes -- but the merged rows are then no longer one command's on one CPU: ``merged``
    keeps each part's kernels and the record's ``kernels`` becomes ``"mixed"``."""
    folder, other = Path(folder), Path(other)
    paths = [next(Path(f).glob("*.json")) for f in (folder, other)]
    records = [json.loads(path.read_text()) for path in paths]
    differ = [
        key
        for key in SAME_EXPERIMENT
        if with_defaults(key, records[0].get(key), _names(records, key))
        != with_defaults(key, records[1].get(key), _names(records, key))
        and not (other_cpu and key == "kernels")
    ]
    shape = [{(r["method"], r["obs_mode"], r["total_steps"]) for r in record["runs"]} for record in records]
    if differ or not shape[1] <= shape[0]:  # other seeds of all the curves, or of some (``--methods vd l2``)
        hint = (
            " (rows from another CPU: merge them with other_cpu, rederive --add-other-cpu)"
            if differ == ["kernels"]
            else ""
        )
        raise ValueError(
            f"{other} is not {folder}'s experiment with other seeds: it differs in "
            f"{', '.join(differ) or 'its runs (methods, observations or budgets)'}{hint}"
        )
    seeds = [{run["seed"] for run in record["runs"]} for record in records]
    curve_seeds = [{(run["label"], run["method"], run["seed"]) for run in record["runs"]} for record in records]
    if shared := curve_seeds[0] & curve_seeds[1]:  # a curve's seed run twice; other curves may add that seed
        raise ValueError(
            f"{folder} and {other} share seeds {sorted({seed for *_, seed in shared})} "
            f"of {', '.join(sorted({label for label, *_ in shared}))}"
        )
    name = records[0]["experiment"]
    rows = read_rows(results_file(folder, name)) + read_rows(results_file(other, name))
    curves = list(dict.fromkeys((row["label"], row["method"]) for row in rows))
    rows.sort(key=lambda row: (curves.index((row["label"], row["method"])), row["seed"]))
    write_csv(results_file(folder, name), rows)
    runs = records[0]["runs"] + records[1]["runs"]
    order = list(dict.fromkeys((run["label"], run["method"]) for run in runs))
    merged = [
        entry
        for record, folder_seeds in zip(records, seeds)
        for entry in record.get("merged")
        or [
            {
                **{key: record.get(key) for key in ("command", "argv", "state_dir", "wall_time_s")},
                "seeds": sorted(folder_seeds),
                "labels": list(dict.fromkeys(run["label"] for run in record["runs"])),  # its curves (batches.py)
                "kernels": record.get("kernels") or NOT_RECORDED,
            }
        ]
    ]
    merged.append(
        {
            "command": shlex.join(
                [
                    "python",
                    "-m",
                    "vdtutorial",
                    "rederive",
                    recorded_path(folder),
                    "--add-other-cpu" if other_cpu else "--add",
                    recorded_path(other),
                ]
            )
        }
    )
    parts = shlex.split(records[0]["command"])
    start = parts.index("--seeds") + 1
    end = next((i for i in range(start, len(parts)) if parts[i].startswith("--")), len(parts))
    per_curve = {
        tuple(sorted(run["seed"] for run in runs if (run["label"], run["method"]) == curve)) for curve in order
    }
    # one command makes all the rows only when every curve has the same seeds; else the first part's stays
    command = (
        shlex.join(parts[:start] + [str(seed) for seed in sorted(seeds[0] | seeds[1])] + parts[end:])
        if len(per_curve) == 1
        else records[0]["command"]
    )
    records[0].update(
        command=command,
        runs=sorted(runs, key=lambda run: (order.index((run["label"], run["method"])), run["seed"])),
        argv=None,
        merged=merged,
        wall_time_s=sum(entry.get("wall_time_s", 0.0) for entry in merged),
        **{key: with_defaults(key, records[0][key], _names(records, key)) for key in CONFIGS if key in records[0]},
    )
    if records[0].get("kernels") != records[1].get("kernels"):
        records[0]["kernels"] = "mixed"
    paths[0].write_text(json.dumps(records[0], indent=1, default=str))
    return rederive(folder)


def format_summary(result: ExperimentResult) -> str:
    """The final level of every curve with its band as the figure draws it (clipped to the values the measure can
    take; with one seed, the words that there is none), the fig4-style "VD reaches L2" line if any, the
    pre-registered plan the claims were tested by, if any, and where the files went."""
    lines = []
    for label, final in result.summary["final"].items():
        seeds = f"{final['seeds']} seed{'s' if final['seeds'] != 1 else ''}"
        if math.isfinite(final["low"]):
            low, high = band_limits(final["low"], final["high"], result.metric)  # as the figure draws it
            clipped = ", clipped to possible values" if (low, high) != (final["low"], final["high"]) else ""
            band = f"{CONFIDENCE:.0%} band {low:.2f} to {high:.2f}{clipped}, {seeds}"
        else:
            band = f"{seeds}: no band from a single sample"
        lines.append(f"{label:>32}: final {final['mean']:.2f} ({band})")
    if "vd_reaches_l2_final" in result.summary:
        lines.append(result.summary["vd_reaches_l2_final"]["text"])
    if result.record.get("plan"):
        lines.append(f"plan {result.record['plan']['name']}: {result.record['plan']['rule']}")
    lines.append(f"wrote {result.out}")
    return "\n".join(lines)
