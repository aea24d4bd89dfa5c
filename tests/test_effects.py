"""Effect sizes of the paper's claims: Welch intervals, the bootstrap of steps-to-reach, verdicts."""
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from vdtutorial.experiments import read_rows, results_file
from vdtutorial.experiments.effects import (CLAIMS, claim_effects, claim_table, steps_to_reach_interval, verdict,
                                            welch_interval)
from vdtutorial.settings import DATA_DIR


def test_welch_interval_matches_scipy():
    rng = np.random.default_rng(0)
    a, b = rng.normal(5, 2, 5), rng.normal(3, 4, 7)
    diff, low, high = welch_interval(a, b)
    ci = stats.ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
    assert diff == pytest.approx(a.mean() - b.mean())
    assert (low, high) == pytest.approx((ci.low, ci.high))
    assert all(math.isnan(x) for x in welch_interval([1.0], [2.0, 3.0])[1:])


@pytest.mark.parametrize("low, high, direction, expected", [
    (0.5, 2.0, 1, "confirmed"), (-2.0, -0.5, 1, "contradicted"), (-1.0, 1.0, 1, "not confirmed"),
    (-2.0, -0.5, -1, "confirmed"), (0.5, 2.0, -1, "contradicted"), (math.nan, math.nan, 1, "not confirmed")])
def test_verdicts(low, high, direction, expected):
    assert verdict(low, high, direction) == expected


def _rows(label, method, values_per_seed, steps=200):
    return [{"label": label, "method": method, "seed": s, "iteration": i, "env_steps": (i + 1) * steps, "successes": v}
            for s, values in enumerate(values_per_seed) for i, v in enumerate(values)]


def test_steps_to_reach_is_the_crossing_of_the_seed_mean_curves():
    ramp = np.linspace(0, 20, 100)  # VD rises by 0.2 per iteration; L2 sits at 10
    vd = {"steps": np.arange(1, 101) * 200.0, "values": np.stack([ramp, ramp + 1, ramp - 1])}
    l2 = {"steps": vd["steps"], "values": np.full((3, 100), 10.0)}
    point, low, high = steps_to_reach_interval(vd, l2, window=1)
    assert point == 51 * 200.0  # the seed mean is the ramp: ramp[49] = 9.90, ramp[50] = 10.10, i.e. iteration 51
    # a resample of seeds shifts the mean curve by at most +-1 success, i.e. +-5 iterations of the ramp
    assert point - 5 * 200 <= low < point < high <= point + 5 * 200
    never = {"steps": vd["steps"], "values": np.zeros((3, 100))}
    assert steps_to_reach_interval(never, l2, window=1)[0] == math.inf


def test_claim_effects_of_a_clear_and_an_unclear_comparison():
    rng = np.random.default_rng(1)
    rows = (_rows("VD", "vd", [40 + rng.normal(0, 1, 50) for _ in range(5)])
            + _rows("L2", "l2", [20 + rng.normal(0, 1, 50) for _ in range(5)])
            + _rows("no pre-training", "none", [40 + rng.normal(0, 30, 50) for _ in range(5)]))
    effects = {(e["measure"], e["b"]): e for e in claim_effects("fig4", rows, "successes", window=5)}
    assert effects[("final", "L2")]["verdict"] == "confirmed"
    assert effects[("final", "L2")]["estimate"] == pytest.approx(20, abs=1.5)
    assert effects[("final", "no pre-training")]["verdict"] == "not confirmed"
    assert effects[("steps_to_reach", "L2")]["verdict"] == "confirmed"  # VD is above L2's level from the start
    assert ("final", "IK expert") not in effects  # no expert rows: the claim is left out
    table = claim_table(list(effects.values()))
    assert table.count("\n") == 1 + len(effects) and "**confirmed**" in table


def test_every_figure_has_claims():
    assert set(CLAIMS) == {"fig4", "fig5", "fig6", "fig7"} and all(CLAIMS.values())


SHIPPED = ("fig4", "fig5", "fig6", "fig7", "fig4_rgbd", "fig4_rgbd_fvp0.1", "fig4_state_fvp0.1")


@pytest.mark.parametrize("folder", SHIPPED)
def test_results_page_claim_tables_are_generated_from_the_shipped_rows(folder):
    record = json.loads((DATA_DIR / "results" / folder / f"{folder.split('_')[0]}.json").read_text())
    rows = read_rows(results_file(DATA_DIR / "results" / folder, record['experiment']))
    window = int(re.search(r"over (\d+) iterations", record["smoothing"])[1])
    effects = claim_effects(record["experiment"], rows, record["metric"], window)
    assert claim_table(effects) in (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text()
    stored = [(e["text"], e["verdict"]) for e in record["summary"]["claims"]]
    assert stored == [(e["text"], e["verdict"]) for e in effects]  # NAME.json holds the same effects
