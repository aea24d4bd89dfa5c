"""What the main job (``python -m vdtutorial reproduce``) prints: no line that reads as an error when nothing is
wrong, bands as its figure draws them, and ``--quick`` meaning quick mode, recorded as such."""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from vdtutorial.experiments.curves import Curve
from vdtutorial.experiments.plots import plot_measures
from vdtutorial.experiments.reproduce import small_run_reach_text
from vdtutorial.experiments.results import ExperimentResult, format_summary


def _curve(label, method, mean, low, high, seeds=3):
    return Curve(label, method, np.array([200.0, 400.0]), np.array(mean), np.array(low), np.array(high), seeds)


def test_a_band_below_zero_is_printed_as_the_figure_draws_it():
    curves = {
        "no pre-training": _curve("no pre-training", "none", [1.0, 1.49], [0.1, -0.54], [2.0, 3.53]),
        "VD": _curve("VD", "vd", [2.0, 2.5], [1.0, 1.5], [3.0, 3.5]),
    }
    summary = {
        "final": {
            label: {"mean": c.mean[-1], "low": c.low[-1], "high": c.high[-1], "seeds": c.seeds}
            for label, c in curves.items()
        }
    }
    text = format_summary(
        ExperimentResult("reproduce_quick", "runs/x", [], curves, None, summary, record={"metric": "successes"})
    )
    assert "final 1.49 (95% band 0.00 to 3.53, clipped to possible values, 3 seeds)" in text
    assert "final 2.50 (95% band 1.50 to 3.50, 3 seeds)" in text
    assert not re.search(r"-\d", text)


def test_the_steps_panel_says_lower_is_better():
    curve = _curve("VD", "vd", [1.0, 2.0], [0.5, 1.5], [1.5, 2.5])
    figure = plot_measures({"successes": {"VD": curve}, "steps_per_trajectory": {"VD": curve}}, "t", window=1)
    successes, steps = (ax.get_ylabel() for ax in figure.axes[:2])
    assert "lower is better" in steps and "lower is better" not in successes


@pytest.mark.parametrize(
    "steps, expected",
    [
        (20_000.0, "first reaches L2's final level (1.50) at 2e+04 env steps, 40% of these 50,000"),
        (None, "stays below L2's final level (1.50) over these 50,000 steps"),
    ],
)
def test_the_reach_line_of_a_small_run_gives_no_verdict(steps, expected):
    reach = {"l2_final_level": 1.5, "steps": steps, "fraction_of_budget": None if steps is None else steps / 5e4}
    text = small_run_reach_text(reach, 50_000)
    assert expected in text and "docs/results.md" in text
    assert "not met" not in text


@pytest.mark.pipeline
def test_reproduce_quick_is_quick_mode_and_says_so(tmp_path):
    """Without VDTUTORIAL_QUICK in the environment, ``--quick`` runs the quick budgets, records ``"quick": true``
    and leaves no line that reads as a failure."""
    env = {key: value for key, value in os.environ.items() if key != "VDTUTORIAL_QUICK"}
    env.update(VDTUTORIAL_RUNS=str(tmp_path / "runs"), MPLBACKEND="Agg")
    result = subprocess.run(
        [sys.executable, "-m", "vdtutorial", "reproduce", "--quick", "--workers", "1"],
        env=env,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    out = tmp_path / "runs" / "quick" / "reproduce_quick"
    record = json.loads((out / "reproduce_quick.json").read_text())
    assert record["quick"] is True and record["pretrain_config"]["epochs"] == 4  # quick mode's budget
    printed = result.stdout
    assert f"wrote {out}" in printed
    for alarming in ("not met", "is another pre-training", "error", "band -"):
        assert alarming not in printed.lower(), alarming
