"""The beyond experiment's comparisons (vdtutorial.experiments.beyond), on made-up scores."""
import numpy as np
import pytest

from vdtutorial.experiments.beyond import comparisons, variants
from vdtutorial.experiments.curves import CONFIDENCE


def _rows(level):
    rng = np.random.default_rng(0)
    return [{"label": v.label, "successes": level(v) + rng.normal(0, 0.5)} for v in variants() for _ in range(5)]


def test_comparisons_are_bonferroni_corrected_and_read_the_right_way():
    # DART far above the Sigma it started from, DAgger far below every hand-set Sigma, the rest equal
    level = {"dart": 20.0, "dagger": 0.0, "hand-set": 10.0}
    found = comparisons(_rows(lambda v: level[v.kind]))
    assert len(found) == 12
    assert all(c["confidence"] == pytest.approx(1 - (1 - CONFIDENCE) / 12) for c in found)
    readings = {(c["question"], c["a"]): c["reading"] for c in found}
    assert readings[("learned noise beats the poor Sigma it started from", "VD, DART from Sigma=0.05")] == "a above b"
    assert readings[("DAgger against the paper's Sigma=0.5", "L2, DAgger")] == "a below b"


def test_the_best_hand_set_sigma_is_chosen_per_regulariser():
    found = comparisons(_rows(lambda v: {0.25: 15.0}.get(v.sigma, 5.0) if v.reg == "vd" and v.kind == "hand-set"
                              else {0.05: 15.0}.get(v.sigma, 5.0) if v.kind == "hand-set" else 5.0))
    best = {c["a"].split(",")[0]: c["b"] for c in found if c["question"] == "DAgger against the best hand-set Sigma"}
    assert best == {"VD": "VD, Sigma=0.25", "L2": "L2, Sigma=0.05"}
