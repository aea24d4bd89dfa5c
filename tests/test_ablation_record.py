"""The ablations' record (``python -m vdtutorial ablations RUNS_FIG6 RUNS_FIG5``): made from two synthetic experiment
folders in the layout the figures' experiments write (``FIG.json``, ``FIG.csv.gz`` with the runs' columns), its
numbers checked against an independent computation from the JSON alone (scipy's Welch test and a Holm written here),
an incomplete set refused in one line, the plan's reading on each pattern, and the figure written."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from PIL import Image
from scipy import stats

from vdtutorial.cli import main
from vdtutorial.experiments.ablation_record import ablation_figure, setting_methods
from vdtutorial.experiments.ablations import (
    NOISE_WINS,
    OTHER_PATTERN,
    PLAN_SEEDS,
    PLAN_STEPS,
    PRUNING_WINS,
    RUNS_COMMIT,
    SETTINGS,
    VARIANCES_MATTER,
    ablation_claims,
    ablation_effects,
    plan_reading,
)
from vdtutorial.runner.rows import write_csv

from flat_curves import flat_rows

PLAN = Path(__file__).resolve().parents[1] / "docs" / "plan-ablations-and-image-fig5.md"
#: The smoothing window the synthetic records name, as the figures' records do.
WINDOW = 25
#: Steps per TRPO iteration, as the experiments run them.
ITERATION = 200
#: Each setting's levels by method (vd, l2, vd_unpruned, dropout): at Fig. 6 the pruning wins, at Fig. 5 binary
#: dropout ends above L2 (noise alone), so that the record reads differently per setting. At Fig. 5, VD without
#: pruning ends a little below VD: with these seeds its p-value passes a Holm family of four and fails one of eight.
LEVELS = {
    "fig6": {"vd": 30.0, "l2": 25.0, "vd_unpruned": 25.5, "dropout": 25.0},
    "fig5": {"vd": 28.0, "l2": 24.0, "vd_unpruned": 26.7, "dropout": 27.5},
}
#: Where the refused commands would write: nothing must appear there.
REFUSED = "data/results/refused"
FOLDERS = {"fig6": "ablations_fig6_sigma0.25", "fig5": "ablations_fig5_n2000"}


def run_rows(setting, name: str, seed: int, level: float, rng, iterations: int) -> list[dict]:
    """One run's rows as the experiment writes them (the grid's columns, then TRPO's): successes around ``level``
    with noise from iteration to iteration, 40 to 45 trajectories per iteration."""
    samples, noise = (8000, 0.25) if setting.figure == "fig6" else (2000, 0.5)
    return [
        {
            "label": setting.label(name),
            "method": name,
            "task": "reach",
            "samples": samples,
            "noise": noise,
            "obs_mode": "state",
            "seed": seed,
            "iteration": i,
            "env_steps": (i + 1) * ITERATION,
            "successes": int(max(0, round(level + rng.normal(0, 2.0)))),
            "episodes": int(40 + rng.integers(0, 6)),
            "mean_return": float(rng.normal(-5, 1)),
            "wall_time": 0.1 * (i + 1),
        }
        for i in range(iterations)
    ]


def setting_rows(setting, seed: int = 0, iterations: int = PLAN_STEPS // ITERATION) -> list[dict]:
    """Every run of ``setting`` (its four methods, the plan's ten seeds) with seed-to-seed spread, seeded."""
    rng = np.random.default_rng(seed)
    rows = []
    for name in setting_methods(setting):
        level = LEVELS[setting.figure]["dropout" if name.startswith("dropout@") else name]
        for s in PLAN_SEEDS:
            rows += run_rows(setting, name, s, level + rng.normal(0, 1.0), rng, iterations)
    return rows


def write_folder(folder: Path, setting, rows: list[dict]) -> Path:
    """An experiment folder as :func:`~vdtutorial.experiments.results.run_experiment` lays it out (the record's
    keys the record reads, the rows gzip-compressed)."""
    folder.mkdir(parents=True)
    write_csv(folder / f"{setting.figure}.csv.gz", rows)
    methods = setting_methods(setting)
    record = {
        "experiment": setting.figure,
        "command": f"python -m vdtutorial experiment {setting.figure} --methods {' '.join(methods)} "
        f"--out runs/{folder.name} --state-dir runs/{folder.name}/state",
        "metric": "successes",
        "window": WINDOW,
        "smoothing": f"trailing moving average over {WINDOW} iterations",
        "state_dir": f"runs/{folder.name}/state",
        "wall_time_s": 1.0,
        "kernels": {"torch": "test"},
        "versions": {"vdtutorial": "test"},
        "runs": [{"method": m, "seed": s, "label": setting.label(m)} for m in methods for s in PLAN_SEEDS],
    }
    (folder / f"{setting.figure}.json").write_text(json.dumps(record))
    return folder


@pytest.fixture(scope="module")
def rows_by_setting():
    return {s.figure: setting_rows(s, seed=k) for k, s in enumerate(SETTINGS)}


@pytest.fixture(scope="module")
def project(tmp_path_factory, rows_by_setting):
    """A folder holding data/ and the plan's two run folders, finished; recorded paths are relative to it."""
    root = tmp_path_factory.mktemp("project")
    for s in SETTINGS:
        write_folder(root / "runs" / FOLDERS[s.figure], s, rows_by_setting[s.figure])
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VDTUTORIAL_DATA", str(root / "data"))
        yield root


def _command(project: Path, folders=None, out: str = "data/results/ablations") -> list[str]:
    folders = folders or [f"runs/{FOLDERS[s.figure]}" for s in SETTINGS]
    return ["ablations", *(str(project / f) for f in folders), "--out", str(project / out)]


@pytest.fixture(scope="module")
def record(project):
    assert main(_command(project)) == 0
    return json.loads((project / "data/results/ablations/ablations.json").read_text())


# -- the numbers, computed again from the JSON alone --------------------------------------------------------------
def holm(p_values: list[float], alpha: float = 0.05) -> list[bool]:
    """Holm's step-down rejections, written here apart from the package's."""
    m = len(p_values)
    rejected = [False] * m
    for rank, i in enumerate(np.argsort(p_values)):
        if p_values[i] >= alpha / (m - rank):
            break
        rejected[i] = True
    return rejected


def welch(a, b) -> tuple[float, float, float, float]:
    """Difference of means, its 95% Welch interval and two-sided p-value, from scipy's Welch test."""
    a, b = np.asarray(a), np.asarray(b)
    test = stats.ttest_ind(a, b, equal_var=False)
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    dof = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    half = stats.t.ppf(0.975, dof) * math.sqrt(va + vb)
    diff = a.mean() - b.mean()
    return diff, diff - half, diff + half, float(test.pvalue)


def test_each_runs_final_level_is_its_mean_over_the_last_window(record, rows_by_setting):
    levels = record["final_levels"]["successes"]
    for setting in SETTINGS:
        rows = rows_by_setting[setting.figure]
        for name in setting_methods(setting):
            label = setting.label(name)
            assert levels[label]["seeds"] == list(PLAN_SEEDS) and record["seeds"][label] == list(PLAN_SEEDS)
            expected = [
                np.mean([r["successes"] for r in rows if r["label"] == label and r["seed"] == s][-WINDOW:])
                for s in PLAN_SEEDS
            ]
            assert np.allclose(levels[label]["values"], expected, rtol=0, atol=1e-12), label
    rate = record["final_levels"]["success_rate"]
    label = SETTINGS[0].label("vd")
    seed_rows = [r for r in rows_by_setting["fig6"] if r["label"] == label and r["seed"] == 0][-WINDOW:]
    assert math.isclose(rate[label]["values"][0], np.mean([r["successes"] / r["episodes"] for r in seed_rows]))


def test_the_claims_rederive_from_the_json_alone(record):
    """Estimate, interval, p-value, verdict and Holm verdict of the eight claims, from the per-run levels in the
    JSON with scipy's Welch test and Holm over the eight."""
    claims = record["claims"]
    assert [c["text"] for c in claims] == [c.text for c in ablation_claims()]
    levels = record["final_levels"][record["metric"]]
    p_values = []
    for claim in claims:
        a, b = levels[claim["a"]]["values"], levels[claim["b"]]["values"]
        diff, low, high, p = welch(a, b)
        assert np.allclose([claim["estimate"], claim["low"], claim["high"]], [diff, low, high], rtol=1e-10)
        assert math.isclose(claim["p_value"], p, rel_tol=1e-8)
        material = 0.05 * abs(np.mean(b))
        assert claim["verdict"] == (
            "negligible"
            if (low > 0 or high < 0) and -material < low and high < material
            else "confirmed"
            if low > 0
            else "contradicted"
            if high < 0
            else "not confirmed"
        )
        assert claim["n_a"] == claim["n_b"] == len(PLAN_SEEDS)
        p_values.append(p)
    for claim, rejected in zip(claims, holm(p_values)):
        assert claim["holm_verdict"] == (claim["verdict"] if rejected else "not confirmed"), claim["text"]
    # the synthetic levels make every kind of verdict, so the comparison above checks something; and one claim that
    # Holm over Fig. 5's four alone would keep, which the family of eight does not
    assert {c["holm_verdict"] for c in claims} >= {"contradicted", "confirmed", "not confirmed"}
    kept_by_four = [c for c, rejected in zip(claims[4:], holm(p_values[4:])) if rejected]
    assert [c["text"] for c in kept_by_four if c["holm_verdict"] == "not confirmed"] == [
        "VD without pruning ends at VD's level (2000 demos)"
    ]


def test_the_secondary_measures_are_reported_beside_the_claims(record):
    assert {e["metric"] for e in record["secondary"]} == {"success_rate", "steps_per_trajectory"}
    assert len(record["secondary"]) == 16 and {e["family"] for e in record["claims"]} == {"primary"}
    levels = record["final_levels"]
    for e in record["secondary"]:
        diff, low, high, p = welch(levels[e["metric"]][e["a"]]["values"], levels[e["metric"]][e["b"]]["values"])
        assert np.allclose([e["estimate"], e["low"], e["high"], e["p_value"]], [diff, low, high, p], rtol=1e-8)


def test_the_record_names_its_sources_and_commands_as_relative_paths(project, record):
    folders = " ".join(f"runs/{FOLDERS[s.figure]}" for s in SETTINGS)
    assert record["command"] == f"python -m vdtutorial ablations {folders} --out data/results/ablations"
    kept = " ".join(f"data/results/ablations/rows/{FOLDERS[s.figure]}" for s in SETTINGS)
    assert record["rederive_command"] == f"python -m vdtutorial ablations {kept} --out data/results/ablations"
    assert [s["folder"] for s in record["sources"]] == folders.split()
    assert [s["command"].split()[4] for s in record["sources"]] == ["fig6", "fig5"]
    assert f"**Worktree commit the runs are made from:** `{record['runs_commit']}`" in PLAN.read_text()
    assert record["runs_commit"] == RUNS_COMMIT
    assert "/" + str(project).strip("/") not in json.dumps(record)
    assert (project / "data/results/ablations/ablations.json").stat().st_size < 100_000


def test_the_kept_rows_make_the_same_record_and_are_not_shipped(project, record):
    """The command given the folders it kept makes the same record (it is its own rederive, and still names the runs'
    folders and the command that first made it), and what it kept stays out of a learner's copy: only the JSON and
    the figure ship."""
    from vdtutorial.course.chapters import shipped_files

    kept = [f"data/results/ablations/rows/{FOLDERS[s.figure]}" for s in SETTINGS]
    assert main(_command(project, kept)) == 0
    again = json.loads((project / "data/results/ablations/ablations.json").read_text())
    assert again == record
    (project / "notebooks").mkdir(exist_ok=True)
    (project / "notebooks" / "00_start.ipynb").write_text("{}")
    shipped = {p.as_posix() for p in shipped_files(project) if p.parts[0] == "data"}
    assert shipped == {"data/results/ablations/ablations.json", "data/results/ablations/ablations.png"}


# -- refusals ---------------------------------------------------------------------------------------------------
def _error(capsys) -> str:
    """The one error line of a refused command (quick mode's notice aside)."""
    lines = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("[quick mode")]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


def test_a_missing_folder_is_refused(project, capsys):
    assert main(_command(project, ["runs/nowhere", f"runs/{FOLDERS['fig5']}"], REFUSED)) == 2
    assert "runs/nowhere: no such folder" in _error(capsys)
    assert not (project / REFUSED).exists()


def test_an_unfinished_experiment_is_refused(project, capsys):
    """A folder whose experiment still runs has its states but no record yet (the record is written last)."""
    (project / "runs/running/state").mkdir(parents=True)
    assert main(_command(project, [f"runs/{FOLDERS['fig6']}", "runs/running"], REFUSED)) == 2
    assert "has no fig5.json: its experiment has not finished" in _error(capsys)


def test_the_folders_in_the_wrong_order_are_refused(project, capsys):
    assert main(_command(project, [f"runs/{FOLDERS['fig5']}", f"runs/{FOLDERS['fig6']}"], REFUSED)) == 2
    assert "holds fig5.json, not fig6's runs" in _error(capsys)


def test_an_incomplete_set_is_refused_naming_what_is_missing(project, rows_by_setting, capsys):
    """One run stopped short of 3e5 steps and one seed missing: refused, both named, nothing written."""
    fig6 = SETTINGS[0]
    short, gone = fig6.label("vd_unpruned"), fig6.label(fig6.dropout)
    rows = [
        r
        for r in rows_by_setting["fig6"]
        if not (r["label"] == short and r["seed"] == 3 and r["env_steps"] > PLAN_STEPS // 2)
        and not (r["label"] == gone and r["seed"] in (8, 9))
    ]
    write_folder(project / "runs/partial", fig6, rows)
    assert main(_command(project, ["runs/partial", f"runs/{FOLDERS['fig5']}"], REFUSED)) == 2
    error = _error(capsys)
    assert f"missing or short: {short} seed 3; {gone} seeds 8, 9" in error, error
    assert f"every run to {PLAN_STEPS} env steps" in error
    assert not (project / REFUSED).exists()


# -- the plan's reading -----------------------------------------------------------------------------------------
def _pattern(fig6: dict[str, float], fig5: dict[str, float] | None = None) -> list[dict]:
    """Flat curves of ten seeds per method and setting around the levels given (fig5's: fig6's unless given)."""
    offsets = np.linspace(-0.5, 0.5, 10)
    rows = []
    for s, levels in zip(SETTINGS, (fig6, fig5 or fig6)):
        for name in setting_methods(s):
            level = levels["dropout" if name.startswith("dropout@") else name]
            rows += flat_rows(s.label(name), name, dict(enumerate(level + offsets)))
    return rows


def _reading(fig6, fig5=None) -> dict[str, str]:
    return plan_reading(ablation_effects(_pattern(fig6, fig5), "successes", window=1))


@pytest.mark.parametrize(
    ("levels", "expected"),
    [
        ({"vd": 30, "l2": 25, "vd_unpruned": 25, "dropout": 25}, PRUNING_WINS),
        ({"vd": 30, "l2": 25, "vd_unpruned": 30, "dropout": 30}, NOISE_WINS),
        ({"vd": 30, "l2": 25, "vd_unpruned": 30, "dropout": 25}, VARIANCES_MATTER),
        ({"vd": 30, "l2": 20, "vd_unpruned": 20, "dropout": 25}, f"{PRUNING_WINS}; and {NOISE_WINS}"),
    ],
    ids=["pruning", "noise", "variances", "pruning-and-noise"],
)
def test_each_pattern_reads_as_the_plan_says(levels, expected):
    reading = _reading(levels)
    assert reading == {"fig6": f"fig6, Sigma = 0.25: {expected}", "fig5": f"fig5, 2000 demos: {expected}"}


def test_another_pattern_is_given_as_it_is_with_its_intervals():
    """Every method at one level: no reading of the plan's holds, and the four claims are given with their effects,
    intervals and Holm verdicts."""
    reading = _reading({"vd": 25, "l2": 25, "vd_unpruned": 25, "dropout": 25})
    for figure, sentence in reading.items():
        assert sentence.startswith(f"{figure}, ") and OTHER_PATTERN in sentence
        assert len(re.findall(r"\+0 \(-0\.\d+ to \+0\.\d+\), not confirmed", sentence)) == 4, sentence


def test_the_settings_are_read_apart():
    reading = _reading(
        {"vd": 30, "l2": 25, "vd_unpruned": 25, "dropout": 25}, {"vd": 30, "l2": 25, "vd_unpruned": 30, "dropout": 30}
    )
    assert reading == {"fig6": f"fig6, Sigma = 0.25: {PRUNING_WINS}", "fig5": f"fig5, 2000 demos: {NOISE_WINS}"}


def test_the_record_reads_its_own_verdicts(record):
    assert record["reading"] == {
        "fig6": f"fig6, Sigma = 0.25: {PRUNING_WINS}",
        "fig5": f"fig5, 2000 demos: {NOISE_WINS}",
    }


# -- the figure ---------------------------------------------------------------------------------------------------
def test_the_figure_is_written_with_every_run(project, record):
    with Image.open(project / "data/results/ablations/ablations.png") as image:
        assert image.format == "PNG" and image.width > image.height
    fig = ablation_figure(record["final_levels"]["successes"], "successes", WINDOW)
    assert len(fig.axes) == len(SETTINGS)
    levels = record["final_levels"]["successes"]
    for ax, setting in zip(fig.axes, SETTINGS):
        dots = [c.get_offsets() for c in ax.collections if isinstance(c, PathCollection)]
        assert [len(d) for d in dots] == [len(PLAN_SEEDS)] * 4, setting
        for d, name in zip(dots, setting_methods(setting)):
            assert np.allclose(np.sort(d[:, 1]), np.sort(levels[setting.label(name)]["values"]))
        assert [t.get_text().split("\n")[0] for t in ax.get_xticklabels()] == [
            "VD",
            "L2",
            "VD without pruning",
            "binary dropout,",
        ]


def test_the_results_page_carries_the_shipped_table():
    """The results page's ablation table is the function's output on the shipped record, word for word."""
    from vdtutorial.experiments.ablation_record import ablation_table

    root = Path(__file__).resolve().parents[1]
    shipped = json.loads((root / "data" / "results" / "ablations" / "ablations.json").read_text())
    table = ablation_table(shipped)
    assert table in (root / "docs" / "results.md").read_text()
    assert table.count("\n| ") == len(shipped["claims"]) + len(shipped["secondary"])
