"""Image pre-training stopped on the held-out loss against the fixed epochs (experiments.pretrain_stop): the
settings it compares, its grid and its comparison (the grid itself is a long image run, not run here)."""

from pathlib import Path

import numpy as np
import pytest

from vdtutorial.experiments import pretrain_stop as ps
from vdtutorial.experiments.checkpoints import default_config
from conftest import require_locked


@pytest.mark.parametrize("reg", ["vd", "l2"])
def test_the_stopped_config_keeps_the_fixed_runs_warm_up_in_epochs(reg):
    fixed, stopped = default_config(reg, "rgbd"), ps.stop_config(reg)
    assert stopped.patience is not None and stopped.epochs > fixed.epochs
    assert stopped.beta_warmup * stopped.epochs == pytest.approx(fixed.beta_warmup * fixed.epochs)
    changed = {k for k in vars(fixed) if getattr(fixed, k) != getattr(stopped, k)}
    assert changed == {"epochs", "beta_warmup", "patience"}


def test_the_grid_scores_every_checkpoint_before_rl_and_runs_rl_from_each():
    jobs = ps.jobs((0, 1), Path("/tmp/out"), Path("/tmp/out/runs"))
    pre, rl = jobs[:8], jobs[8:]
    assert all(isinstance(job, ps.PreRLJob) for job in pre) and len(rl) == 8
    assert {(job.kind, job.reg, job.seed) for job in pre} == {(j.kind, j.spec.method, j.spec.seed) for j in rl}
    assert len({job.state_path for job in jobs}) == len(jobs)  # no two jobs share a state file
    stopped = [job for job in rl if job.kind == ps.STOPPED]
    assert all(job.pretrain_config.patience == ps.stop_config(job.spec.method).patience for job in stopped)
    assert all(job.spec.total_steps == ps.rl_steps() for job in rl)


def test_the_comparison_is_stopped_minus_fixed_per_method():
    rows = []
    for kind, shift in ((ps.FIXED, 0.0), (ps.STOPPED, 2.0)):
        for reg in ("vd", "l2"):
            for seed in (0, 1, 2):
                rows.append(
                    {
                        "kind": kind,
                        "method": reg,
                        "seed": seed,
                        "stage": "pre-RL",
                        "epochs_run": 40 + 10 * shift,
                        "val_mse": 0.02,
                        "successes": 10 + shift + seed,
                    }
                )
                rows += [
                    {
                        "kind": kind,
                        "method": reg,
                        "seed": seed,
                        "stage": "RL",
                        "successes": 30 + shift + i,
                        "env_steps": 200 * (i + 1),
                    }
                    for i in range(3)
                ]
    comparison = ps.compare(rows, (0, 1, 2))
    assert [c["measure"].split()[0] for c in comparison[:4]] == ["epochs", "held-out", "successes", "successes"]
    epochs, _, pre_rl, rl = comparison[:4]
    assert epochs["method"] == "vd" and epochs["estimate"] == pytest.approx(20.0)
    assert pre_rl["stopped"] == [12.0, 13.0, 14.0] and pre_rl["estimate"] == pytest.approx(2.0)
    assert rl["stopped"] == [33.0] * 3 and rl["fixed"] == [31.0] * 3
    assert rl["measure"].endswith("first 600 RL steps")  # the rows' own budget, whatever the reader's mode


def _comparison(pre_rl: tuple[float, float], rl: tuple[float, float]) -> list[dict]:
    """A comparison whose two success measures have the given intervals, and wide ones elsewhere."""

    def measure(name, low, high):
        return {"method": "vd", "measure": name, "low": low, "high": high}

    return [
        measure("epochs of cloning", 30.0, 90.0),
        measure("held-out MSE of the kept mu", -0.01, -0.001),
        measure("successes per 200 steps before RL (mean action)", *pre_rl),
        measure("successes per 200 steps, mean over the first 10000 RL steps", *rl),
    ]


def test_only_an_interval_of_the_successes_that_excludes_zero_is_material():
    # the epochs and the held-out error differ here, but they are how the stop got there, not what RL starts from
    assert not ps.is_material(_comparison((-5.0, 8.0), (-1.0, 1.0)))
    assert ps.is_material(_comparison((0.5, 8.0), (-1.0, 1.0)))
    assert ps.is_material(_comparison((-5.0, 8.0), (-9.0, -0.1)))


@pytest.fixture(scope="module")
def shipped():
    import json

    from vdtutorial.experiments import read_rows, results_file
    from vdtutorial.settings import data_dir

    folder = data_dir() / "results" / "pretrain_stop"
    return json.loads((folder / "pretrain_stop.json").read_text()), read_rows(results_file(folder, "pretrain_stop"))


def test_the_shipped_comparison_is_its_rows_and_its_verdict_follows_the_rule(shipped):
    require_locked("scipy")
    record, rows = shipped
    assert not record["quick"] and record["seeds"] == [0, 1, 2] and record["rl_steps"] == 50 * 200
    assert record["comparison"] == ps.compare(rows, record["seeds"])
    assert record["material"] == ps.is_material(record["comparison"])
    assert len([r for r in rows if r["stage"] == "pre-RL"]) == 12
    assert len([r for r in rows if r["stage"] == "RL"]) == 12 * 50
    fixed = [r for r in rows if r["stage"] == "pre-RL" and r["kind"] == ps.FIXED]
    assert {r["epochs_run"] for r in fixed} == {40}  # the figures' checkpoints, found as shipped


def test_the_results_page_and_appendix_a1_print_what_the_record_gives(shipped):
    import json

    root = Path(__file__).resolve().parents[1]  # the checkout: docs/ and notebooks/ are not installed with the package
    record, _ = shipped
    page = (root / "docs" / "results.md").read_text()
    block = "\n".join("    " + line for line in ps.format_comparison(record).splitlines())
    assert block in page
    assert ("not material" in block) == (not record["material"])
    chapter = json.loads((root / "notebooks" / "A1_pretraining_in_detail.ipynb").read_text())
    code = "".join("".join(c["source"]) for c in chapter["cells"] if c["cell_type"] == "code")
    assert "format_comparison(json.loads(stop_file.read_text()))" in code and 'with_suffix(".png")' in code


def test_the_figure_is_titled_for_images_and_its_bands_stay_in_range(shipped):
    from matplotlib.collections import PolyCollection

    from vdtutorial.experiments.measures import MEASURES, measures_of

    record, rows = shipped
    fig = ps.plot(rows, record["seeds"])
    title = fig.get_suptitle()
    assert "held-out loss" in title and "RGBD images" in title and "1e4 env steps" in title and "3 seeds" in title
    for ax, measure in zip(fig.axes, measures_of("successes")):
        floor, ceiling = MEASURES[measure].feasible
        thin = [line for line in ax.lines if line.get_linewidth() < 1]
        assert len(thin) == 4 * 3  # every seed of the four kinds of run
        for band in (c for c in ax.collections if isinstance(c, PolyCollection)):
            y = np.concatenate([path.vertices[:, 1] for path in band.get_paths()])
            assert floor - 1e-9 <= y.min() and y.max() <= ceiling + 1e-9, measure
