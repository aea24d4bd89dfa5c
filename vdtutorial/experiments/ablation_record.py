"""The ablations' record: the two finished experiment folders of the plan turned into one shipped record.

The plan (``docs/plan-ablations-and-image-fig5.md``, section 2) runs each setting as one command of the figures'
experiments, which writes its folder as every experiment does (``FIG.json``, ``FIG.csv.gz``, ``FIG.png``:
:func:`~vdtutorial.experiments.results.run_experiment`). :func:`ablation_record` reads both folders, refuses them
unless every run of the plan is there to the plan's budget (its stopping rule: all runs, no early stop), judges the
eight claims as one Holm family on the paper's metric (:func:`~vdtutorial.experiments.ablations.ablation_effects`),
reads the verdicts as the plan fixed before the runs (:func:`~vdtutorial.experiments.ablations.plan_reading`) and
writes:

``ablations.json``
    the claims (estimate, 95% interval, p-value, plain and Holm verdicts) on the paper's metric, and beside them,
    reported but not read by the plan, the same comparisons on the two secondary measures; each run's final level on
    every measure, so that every number of the record can be computed again from the JSON alone (Welch's t on those
    levels, Holm over the eight); the seeds of each curve; the plan's reading; the source folders, their commands and
    the worktree commit the runs were made from, as paths relative to the folder that holds ``data/``.
``ablations.png``
    one panel per setting: each run's final level as a dot per method, the mean and its 95% interval.
``rows/FOLDER/FIG.{json,csv.gz}``
    each source folder's record and rows as the experiment wrote them. They are kept in the repository but not
    shipped (``rows`` is one of the folders :func:`vdtutorial.course.chapters.shipped_files` leaves out): the JSON
    above carries every number the record reports, and the rows of 80 runs would not fit the shipped data's size.
    The same command given these kept folders makes the record again.

Not taught in a chapter: the runs it records were started after the chapters' results (the plan is in docs/).
"""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy import stats

from vdtutorial.experiments.ablations import (
    PLAN_SEEDS,
    PLAN_STEPS,
    RUNS_COMMIT,
    SETTINGS,
    AblationSetting,
    ablation_effects,
    plan_reading,
)
from vdtutorial.experiments.curves import CONFIDENCE, record_window
from vdtutorial.experiments.effects import per_run, run_summaries
from vdtutorial.experiments.measures import MEASURES, measures_of
from vdtutorial.experiments.paths import data_dir, recorded_path
from vdtutorial.experiments.plots import save_png
from vdtutorial.methods import method
from vdtutorial.runner.rows import read_rows, results_file

#: The record's name: its folder's files are ``NAME.json`` and ``NAME.png``.
NAME = "ablations"
#: The sub-folder of the record that keeps the source folders' records and rows (not shipped).
KEPT = "rows"
#: The methods of each setting, in the order the figure shows them: the two of the paper, then the two ablations.
ORDER = ("vd", "l2", "vd_unpruned", "dropout")


def setting_methods(setting: AblationSetting) -> tuple[str, ...]:
    """The four methods of ``setting`` by their names in the method table (binary dropout at its matched rate)."""
    return tuple(setting.dropout if m == "dropout" else m for m in ORDER)


def setting_record(folder: str | Path, setting: AblationSetting) -> dict:
    """The JSON record of ``setting``'s experiment folder, refused (ValueError, one line) when the folder is missing,
    holds another experiment, or has no record yet (an experiment writes it after all its runs)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder (the plan's command for {setting.figure} makes it)")
    record_path, rows_path = folder / f"{setting.figure}.json", results_file(folder, setting.figure)
    if not record_path.is_file():
        others = sorted(p.name for p in folder.glob("*.json"))
        if others:
            raise ValueError(f"{folder} holds {', '.join(others)}, not {setting.figure}'s runs ({record_path.name})")
        raise ValueError(
            f"{folder} has no {record_path.name}: its experiment has not finished (the record is written after all "
            "its runs; rerun the plan's command to continue it)"
        )
    if not rows_path.is_file():
        raise ValueError(f"{folder} has {record_path.name} but no {rows_path.name}: not an experiment's folder")
    return json.loads(record_path.read_text())


def setting_rows(folder: str | Path, setting: AblationSetting, steps: int = PLAN_STEPS, seeds=PLAN_SEEDS) -> list[dict]:
    """The rows of ``setting``'s four methods and ``seeds`` in its experiment folder, refused (ValueError, one line
    naming every run missing or short) unless each of those runs reached ``steps`` env steps."""
    folder = Path(folder)
    rows = read_rows(results_file(folder, setting.figure))
    reached: dict[str, dict[int, float]] = {}
    for row in rows:
        run = reached.setdefault(row["label"], {})
        run[row["seed"]] = max(run.get(row["seed"], 0), row["env_steps"])
    missing = []
    for name in setting_methods(setting):
        label = setting.label(name)
        short = [s for s in seeds if reached.get(label, {}).get(s, 0) < steps]
        if short:
            missing.append(f"{label} seed{'s' if len(short) > 1 else ''} {', '.join(map(str, short))}")
    if missing:
        raise ValueError(
            f"{folder}: incomplete, the plan needs every run to {steps} env steps; missing or short: "
            + "; ".join(missing)
        )
    labels = {setting.label(name) for name in setting_methods(setting)}
    return [row for row in rows if row["label"] in labels and row["seed"] in seeds]


def final_levels(rows: list[dict], metric: str, window: int) -> dict[str, dict[str, dict]]:
    """Each run's final level (its mean over the last ``window`` iterations) on every measure:
    ``{measure: {label: {"seeds": [...], "values": [...]}}}``, the numbers the claims compare."""
    levels = {}
    for measure in measures_of(metric):
        groups = per_run(rows, measure)
        levels[measure] = {
            label: {
                "seeds": [int(s) for s in group["seeds"]],
                "values": [float(v) for v in run_summaries(group, "final", window)],
            }
            for label, group in groups.items()
        }
    return levels


def ablations_command(folders, out) -> str:
    """The command line that makes the record from ``folders`` into ``out``, paths as a shipped record writes them."""
    return shlex.join(
        ["python", "-m", "vdtutorial", "ablations", *map(recorded_path, folders), "--out", recorded_path(out)]
    )


def _keep(folder: Path, figure: str, kept: Path) -> None:
    """Copy a source folder's record and rows into the record's kept folder (nothing when they are already there)."""
    kept.mkdir(parents=True, exist_ok=True)
    for path in (folder / f"{figure}.json", results_file(folder, figure)):
        if path.resolve() != (kept / path.name).resolve():
            shutil.copyfile(path, kept / path.name)


def _origins(folders: list[Path], kept: list[Path], out: Path) -> list[Path]:
    """The experiment folders the runs were first read from: ``folders`` themselves, except a folder that is already
    the record's kept copy, whose origin the record being made again names (so that making the record again from
    its kept rows, its ``rederive_command``, keeps the command and folders of the runs it was judged from)."""
    previous, named = out / f"{NAME}.json", {}
    try:
        named = {s["kept_as"]: s["folder"] for s in json.loads(previous.read_text())["sources"]}
    except (OSError, ValueError, KeyError, TypeError):
        pass  # no earlier record, or one this command did not write: the folders given are the origins
    project = data_dir().resolve().parent
    return [
        project / named[recorded_path(keep)]
        if folder.resolve() == keep.resolve() and recorded_path(keep) in named
        else folder
        for folder, keep in zip(folders, kept)
    ]


def ablation_record(folders, out: str | Path, steps: int = PLAN_STEPS, seeds=PLAN_SEEDS, settings=SETTINGS) -> dict:
    """Turn the plan's two finished experiment folders (``folders``, in the order of ``settings``: Fig. 6 at
    Sigma = 0.25, then Fig. 5 at 2000 demonstrations) into the record in ``out``
    (module docstring, "and writes:"). Returns the record as written to ``ablations.json``."""
    folders, out = [Path(f) for f in folders], Path(out)
    if len(folders) != len(settings):
        raise ValueError(f"give {len(settings)} folders, one per setting ({', '.join(s.figure for s in settings)})")
    records = [setting_record(folder, s) for folder, s in zip(folders, settings)]  # every folder, before any rows
    metrics, windows = {r["metric"] for r in records}, {record_window(r) for r in records}
    if len(metrics) != 1 or len(windows) != 1:
        raise ValueError(
            f"the folders differ in their metric or smoothing window: {sorted(metrics)}, {sorted(windows)}"
        )
    metric, window = metrics.pop(), windows.pop()
    rows = [row for folder, s in zip(folders, settings) for row in setting_rows(folder, s, steps, seeds)]
    effects = ablation_effects(rows, metric, window)
    levels = final_levels(rows, metric, window)
    kept = [out / KEPT / folder.name for folder in folders]
    for folder, setting, keep in zip(folders, settings, kept):
        _keep(folder, setting.figure, keep)
    origins = _origins(folders, kept, out)
    record = {
        "record": NAME,
        "plan": "docs/plan-ablations-and-image-fig5.md, section 2",
        "command": ablations_command(origins, out),
        "rederive_command": ablations_command(kept, out),
        "runs_commit": RUNS_COMMIT,
        "metric": metric,
        "measures": list(measures_of(metric)),
        "window": window,
        "steps": steps,
        "seeds": {label: entry["seeds"] for label, entry in levels[metric].items()},
        "confidence": CONFIDENCE,
        "test": "Welch's t, two-sided, on each run's final level; the eight claims on the paper's metric are one "
        "family, Holm at family-wise 5% (holm_verdict); the secondary measures are reported, not read by the plan",
        "claims": [e for e in effects if e["family"] == "primary"],
        "secondary": [e for e in effects if e["family"] == "secondary"],
        "reading": plan_reading(effects, settings),
        "final_levels": levels,
        "sources": [
            {
                "setting": setting.figure,
                "data_set": setting.curve_suffix,
                "dropout_rate": setting.dropout_rate,
                "folder": recorded_path(origin),
                "kept_as": recorded_path(keep),
                "command": source.get("command"),
                "state_dir": source.get("state_dir"),
                "kernels": source.get("kernels"),
                "versions": source.get("versions"),
                "wall_time_s": source.get("wall_time_s"),
            }
            for origin, setting, keep, source in zip(origins, settings, kept, records)
        ],
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{NAME}.json").write_text(json.dumps(record, indent=1, default=str))
    save_png(ablation_figure(levels[metric], metric, window, settings), out / f"{NAME}.png", 120)
    return record


def ablation_table(record: dict) -> str:
    """The record's claims as Markdown, the primary family on the paper's metric first, then the secondary measures:
    each claim's means, effect with its 95% interval, p-value, seeds and Holm verdict (the results page's table is
    generated by this), and under it the plan's reading of each setting."""
    lines = [
        "| claim | metric | mean a / mean b | effect (95% interval) | p | seeds | Holm |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in (*record["claims"], *record["secondary"]):
        lines.append(
            f"| {e['text']} | {e['metric']} | {e['mean_a']:.3g} / {e['mean_b']:.3g} | {e['estimate']:+.3g} "
            f"({e['low']:+.3g} to {e['high']:+.3g}) | {e['p_value']:.2g} | {e['n_a']} / {e['n_b']} | "
            f"{e['holm_verdict']} |"
        )
    lines.append("")
    lines += [f"- the plan's reading, {reading}" for reading in record["reading"].values()]
    return "\n".join(lines)


def ablation_figure(levels: dict[str, dict], metric: str, window: int, settings=SETTINGS) -> Figure:
    """One panel per setting: each run's final level (``levels``, by curve label) as a dot per method, spread
    sideways by seed so that equal levels stay visible, and the mean over seeds with its 95% Student-t interval."""
    fig = Figure(figsize=(5.2 * len(settings), 4.6), layout="constrained")
    axes = fig.subplots(1, len(settings), squeeze=False).ravel()
    for ax, setting in zip(axes, settings):
        names = setting_methods(setting)
        for x, name in enumerate(names):
            entry, values = method(name), np.asarray(levels[setting.label(name)]["values"])
            offsets = np.linspace(-0.18, 0.18, len(values)) if len(values) > 1 else np.zeros(1)
            ax.scatter(x + offsets, values, s=14, color=entry.colour, alpha=0.6, linewidths=0)
            mean, (low, high) = float(values.mean()), _mean_interval(values)
            ax.errorbar(x + 0.32, mean, yerr=[[mean - low], [high - mean]], fmt="o", color="black", capsize=4, ms=4)
        ax.set_xticks(range(len(names)), [method(name).label.replace(", ", ",\n") for name in names], fontsize=8)
        ax.set_title(f"{setting.figure}: {setting.curve_suffix.replace('=', ' = ')}", fontsize=10)
        ax.set_ylabel(MEASURES[metric].label, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(
        f"Ablations: each run's final level (mean over the last {window} iterations), state mode; "
        f"black: mean over seeds, {CONFIDENCE:.0%} interval",
        fontsize=10,
    )
    return fig


def _mean_interval(values: np.ndarray) -> tuple[float, float]:
    """The Student-t interval of the mean of ``values`` (both ends the mean with one value)."""
    if len(values) < 2:
        return float(values.mean()), float(values.mean())
    half = stats.t.ppf((1 + CONFIDENCE) / 2, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values))
    return float(values.mean() - half), float(values.mean() + half)
