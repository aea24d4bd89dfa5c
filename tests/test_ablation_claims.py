"""The ablations' claims as the plan fixed them before the runs (docs/plan-ablations-and-image-fig5.md, section 2):
the same methods, rates, settings and claims as the plan's text, one Holm family of eight on the paper's metric, and
verdicts that read as the plan says on curves made to show each pattern."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vdtutorial.experiments.ablations import SETTINGS, ablation_claims, ablation_effects

from flat_curves import flat_rows


PLAN = Path(__file__).resolve().parents[1] / "docs" / "plan-ablations-and-image-fig5.md"


def _class(levels: dict[str, float], spread: float = 0.5) -> list[dict]:
    """Ten seeds of every curve of both settings, around ``levels`` (by method: vd, l2, vd_unpruned, dropout)."""
    offsets = np.linspace(-spread, spread, 10)
    rows = []
    for s in SETTINGS:
        for method in ("vd", "l2", "vd_unpruned", s.dropout):
            level = levels["dropout" if method.startswith("dropout@") else method]
            rows += flat_rows(s.label(method), method.split("@")[0], dict(enumerate(level + offsets)))
    return rows


def test_the_claims_are_the_plans():
    """The rates and method names are the ones the plan measured and named before the runs, and its commands make
    the curves the claims compare."""
    plan = PLAN.read_text()
    for s in SETTINGS:
        assert f"`{s.dropout}`" in plan
        command = re.search(rf"experiment {s.figure} [^\n]*--methods vd l2 vd_unpruned {re.escape(s.dropout)}", plan)
        assert command, s
    claims = ablation_claims()
    assert len(claims) == 8 and {c.measure for c in claims} == {"final"}
    assert {(c.a.split(", ")[0], c.b.split(", ")[0]) for c in claims} == {
        ("VD without pruning", "VD"),
        ("binary dropout", "VD"),
        ("VD without pruning", "L2"),
        ("binary dropout", "L2"),
    }


def test_the_eight_claims_are_one_holm_family():
    """Every claim is found in the rows of both settings and tested once on the primary measure, with Holm over the
    eight, not four per setting: binary dropout ends 0.43 above VD and L2 in both settings (p about 0.01 each), which
    Holm confirms in a family of four (0.01 < 0.05 / 4) and not in one of eight (0.01 > 0.05 / 8)."""
    effects = ablation_effects(_class({"vd": 2, "l2": 2, "vd_unpruned": 2, "dropout": 2.43}), "successes", window=1)
    primary = [e for e in effects if e["family"] == "primary"]
    assert len(primary) == 8
    assert {e["text"] for e in primary} == {c.text for c in ablation_claims()}
    dropout = [e for e in primary if e["text"].startswith("binary dropout")]
    assert len(dropout) == 4 and all(0.05 / 8 < e["p_value"] < 0.05 / 4 for e in dropout), dropout
    assert {e["verdict"] for e in dropout} == {"confirmed"}
    assert {e["holm_verdict"] for e in primary} == {"not confirmed"}


def test_pruning_wins_reads_as_the_plan_says():
    """Curves where VD's win over L2 is its pruning: VD without pruning ends below VD (its claim contradicted) and not
    above L2; binary dropout ends at L2's level."""
    effects = ablation_effects(_class({"vd": 30, "l2": 25, "vd_unpruned": 25, "dropout": 25}), "successes", window=1)
    by_claim = {e["text"]: e["holm_verdict"] for e in effects if e["family"] == "primary"}
    for where in ("Sigma = 0.25", "2000 demos"):
        assert by_claim[f"VD without pruning ends at VD's level ({where})"] == "contradicted"
        assert by_claim[f"VD without pruning ends above L2 ({where})"] != "confirmed"
        assert by_claim[f"binary dropout ends above L2 ({where})"] != "confirmed"
