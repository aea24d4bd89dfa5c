"""Seeds added after a look: the two-stage rule a record's verdict is computed with, checked against scipy."""

import json
import math

import numpy as np
import pytest
from scipy import integrate, stats

from vdtutorial.experiments import read_rows, results_file
from vdtutorial.experiments.effects import (
    claim_effects,
    claim_table,
    per_run,
    run_summaries,
)
from vdtutorial.experiments.looks import looks_of, max_score_p_value, pocock_boundary
from vdtutorial.settings import data_dir

from flat_curves import flat_rows


def _no_look_max_p(score: float, rho: float) -> float:
    """P(max(|Z1|, |Z2|) >= score) by integrating Z1's density times P(|Z2| < score | Z1): independent of the
    bivariate normal CDF the library uses."""
    spread = math.sqrt(1 - rho**2)
    inside = integrate.quad(
        lambda z: (
            stats.norm.pdf(z)
            * (stats.norm.cdf((score - rho * z) / spread) - stats.norm.cdf((-score - rho * z) / spread))
        ),
        -score,
        score,
    )[0]
    return 1 - inside


def test_the_pocock_threshold_of_two_equal_looks_is_the_textbook_one():
    """Pocock's constant for two looks at two-sided 5% is 2.178 (Jennison & Turnbull, Table 2.1)."""
    assert pocock_boundary() == pytest.approx(2.178, abs=5e-4)
    assert max_score_p_value(pocock_boundary()) == pytest.approx(0.05, abs=1e-6)
    assert max_score_p_value(2.9, 0.5) == pytest.approx(_no_look_max_p(2.9, 0.5), abs=1e-6)


def test_a_two_look_record_is_judged_by_the_combination_of_its_stages():
    """Three curves, all at seeds 0-5 at the first look; VD and L2 get seeds 6-13 at the second, "other" does not. The
    VD-L2 claim combines the stages' one-sided Welch p-values with equal weights, and its p-value is the chance that
    either look's score is as far from zero; a claim with one curve extended is judged on the first look's seeds."""
    rng = np.random.default_rng(7)
    vd = {s: 60 + 3.0 * rng.normal() for s in range(14)}
    l2 = {s: 57 + 3.0 * rng.normal() for s in range(14)}
    other = {s: 55 + 3.0 * rng.normal() for s in range(6)}
    rows = (
        flat_rows("VD, 2000 demos", "vd", vd)
        + flat_rows("L2, 2000 demos", "l2", l2)
        + flat_rows("L2, 8000 demos", "l2", other)
    )
    looks = looks_of(
        {
            "looks": [
                {"seeds": {label: list(range(6)) for label in ("VD, 2000 demos", "L2, 2000 demos", "L2, 8000 demos")}},
                {"seeds": {label: list(range(6, 14)) for label in ("VD, 2000 demos", "L2, 2000 demos")}},
            ]
        }
    )
    effects = {
        e["text"]: e
        for e in claim_effects("fig5", rows, "successes", window=5, looks=looks)
        if e["metric"] == "successes" and e["measure"] == "final"
    }

    staged = effects["VD ends above L2 with 2000 demonstrations"]
    stage_p = [
        stats.ttest_ind([vd[s] for s in seeds], [l2[s] for s in seeds], equal_var=False, alternative="greater").pvalue
        for seeds in (range(6), range(6, 14))
    ]
    z1, z2 = stats.norm.isf(stage_p)
    combined = (z1 + z2) / math.sqrt(2)
    assert staged["looks"]["stage_p_one_sided"] == pytest.approx(stage_p, rel=1e-9)
    assert staged["looks"]["combined_p_one_sided"] == pytest.approx(stats.norm.sf(combined), rel=1e-9)
    expected_p = _no_look_max_p(max(abs(z1), abs(combined)), 1 / math.sqrt(2))
    assert staged["p_value"] == pytest.approx(expected_p, rel=1e-4, abs=1e-7)
    all_at_once = stats.ttest_ind(list(vd.values()), list(l2.values()), equal_var=False).pvalue
    assert staged["p_value_all_seeds_at_once"] == pytest.approx(all_at_once, rel=1e-9)
    assert staged["n_a"] == staged["n_b"] == 14  # the interval shown is over all seeds ...
    assert expected_p < 0.05 and staged["verdict"] == "confirmed"
    assert "| 6 + 8 |" in claim_table([staged]) and "(2 looks: sequential rule)" in claim_table([staged])

    one_sided = effects["VD with 2000 demonstrations ends at least as high as L2 with 8000"]
    first = stats.ttest_ind([vd[s] for s in range(6)], list(other.values()), equal_var=False).pvalue
    assert (one_sided["n_a"], one_sided["n_b"]) == (6, 6) and one_sided["p_value"] == pytest.approx(first, rel=1e-9)
    assert "no independent second stage" in claim_table([one_sided])


def test_the_shipped_fig5_keeps_both_looks_and_its_verdict_follows_the_rule():
    """Fig. 5 at 2000 demonstrations ran seeds 0-9, was read, and got seeds 10-22. Seeds 10-22 alone give +13.9
    (+3.2 to +24.6), one-sided p = 0.0065; the inverse-normal combination of the stages one-sided p = 0.00044."""
    folder = data_dir() / "results" / "fig5"
    record = json.loads((folder / "fig5.json").read_text())
    looks = looks_of(record)
    assert looks[0]["VD, 2000 demos"] == list(range(10)) and looks[1] == {
        "VD, 2000 demos": list(range(10, 23)),
        "L2, 2000 demos": list(range(10, 23)),
    }
    groups = per_run(read_rows(results_file(folder, "fig5")), "successes")
    final = {
        label: dict(zip(groups[label]["seeds"], run_summaries(groups[label], "final", 25)))
        for label in ("VD, 2000 demos", "L2, 2000 demos")
    }
    second = [[final[label][s] for s in range(10, 23)] for label in ("VD, 2000 demos", "L2, 2000 demos")]
    test = stats.ttest_ind(*second, equal_var=False, alternative="greater")
    ci = stats.ttest_ind(*second, equal_var=False).confidence_interval(0.95)
    assert (np.mean(second[0]) - np.mean(second[1]), ci.low, ci.high) == pytest.approx((13.9, 3.2, 24.6), abs=0.05)
    assert test.pvalue == pytest.approx(0.0065, abs=5e-5)
    claim = next(
        e
        for e in record["summary"]["claims"]
        if e["text"] == "VD ends above L2 with 2000 demonstrations" and e["metric"] == "successes"
    )
    assert claim["looks"]["stage_p_one_sided"][1] == pytest.approx(test.pvalue, rel=1e-9)
    assert claim["looks"]["combined_p_one_sided"] == pytest.approx(0.00044, abs=5e-6)
    assert claim["holm_verdict"] == "confirmed" and claim["p_value"] > claim["p_value_all_seeds_at_once"]
