"""The learning-curve figures: titles that tell the shipped variants apart, bands inside each measure's range,
one thin line per seed, the expert's band named for what it is."""

import json

import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from vdtutorial.experiments import curves_from_rows, read_rows, results_file
from vdtutorial.experiments.measures import MEASURES, measures_of
from vdtutorial.experiments.plots import figure_title, plot_measures
from vdtutorial.settings import data_dir

RESULTS = data_dir() / "results"
FIG4_VARIANTS = ("fig4", "fig4_rgbd", "fig4_rgbd_fvp0.1", "fig4_state_fvp0.1")


def _record(folder):
    return json.loads((RESULTS / folder / f"{folder.split('_')[0]}.json").read_text())


def test_the_shipped_fig4_variants_have_distinct_titles_naming_input_budget_and_control():
    titles = {folder: _record(folder)["title"] for folder in FIG4_VARIANTS}
    assert len(set(titles.values())) == len(titles)
    assert "state input" in titles["fig4"] and "RGBD images" in titles["fig4_rgbd"]
    assert "1e5 env steps" in titles["fig4_rgbd_fvp0.1"] and "3e5 env steps" in titles["fig4_rgbd"]
    assert all(("control" in title) == folder.endswith("fvp0.1") for folder, title in titles.items())
    assert all(f"{len(_record(folder)['seeds'])} seeds" in title for folder, title in titles.items())


def test_figure_title_names_the_control_only_when_the_fisher_is_subsampled():
    assert "control" not in figure_title("Fig. 4", "state", 300_000, 5)
    assert "10% of each batch" in figure_title("Fig. 4", "rgbd", 100_000, 3, fvp_subsample=0.1)


@pytest.fixture(scope="module")
def rgbd_figure():
    """The image Fig. 4: over 3 seeds, unclipped bands leave every measure's range."""
    record = _record("fig4_rgbd")
    rows = read_rows(results_file(RESULTS / "fig4_rgbd", "fig4"))
    by_measure = {m: curves_from_rows(rows, m, record["window"]) for m in measures_of(record["metric"])}
    return by_measure, plot_measures(by_measure, record["title"], record["window"])


def test_no_band_leaves_its_measures_range(rgbd_figure):
    by_measure, fig = rgbd_figure
    for measure, curves in by_measure.items():  # unclipped, each panel would have a band outside the range
        floor, ceiling = MEASURES[measure].feasible
        assert any(np.nanmin(c.low) < floor or np.nanmax(c.high) > ceiling for c in curves.values()), measure
    for ax, measure in zip(fig.axes, by_measure):
        floor, ceiling = MEASURES[measure].feasible
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert bands
        for band in bands:
            y = np.concatenate([path.vertices[:, 1] for path in band.get_paths()])
            assert floor - 1e-9 <= y.min() and y.max() <= ceiling + 1e-9, measure
        spans = [p for p in ax.patches]  # the expert's band
        for span in spans:
            y = span.get_path().transformed(span.get_patch_transform()).vertices[:, 1]
            assert floor - 1e-9 <= y.min() and y.max() <= ceiling + 1e-9, measure


def test_every_seed_is_drawn_behind_the_mean_and_the_expert_band_is_over_episodes(rgbd_figure):
    by_measure, fig = rgbd_figure
    ax = fig.axes[0]
    learners = [c for c in by_measure["successes"].values() if c.method != "expert"]
    thin = [line for line in ax.lines if line.get_linewidth() < 1]
    assert len(thin) == sum(c.seeds for c in learners)
    expert = by_measure["successes"]["IK expert"]
    labels = [line.get_label() for line in ax.lines]
    assert any(f"over {expert.episodes} evaluation episodes, not seeds" in label for label in labels)
    assert len(fig.axes) == len(by_measure) == 3
