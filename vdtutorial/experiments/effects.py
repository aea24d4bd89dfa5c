"""The paper's claims as effect sizes with 95% intervals over seeds, and a verdict for each.

A curve's band says where one method's mean lies; a claim compares two methods. For every claim of
Section V (Figs. 4-7) this module measures, from the per-run TRPO rows:

final level
    each run's mean metric over its last ``window`` iterations (the smoothed curve's end point);
area under the curve (AUC)
    each run's mean metric over all its iterations: how much was achieved along the way, which is
    what "learns faster" means over a fixed budget;
steps to reach
    the first env step at which the first method's seed-mean smoothed curve reaches the second
    method's final level (the paper's "VD overtakes L2's final performance at ~1.25e5 steps").

The first two are differences of means over seeds with Welch's t interval (unequal variances, the
Welch-Satterthwaite degrees of freedom): seeds are the independent replicates and there are few of
them, so a t interval is the honest choice. The steps-to-reach estimate has no closed form, so its
interval is a percentile bootstrap over seeds (each method's seeds resampled with replacement,
``BOOTSTRAP_SAMPLES`` times, seeded): when a resampled curve never reaches the level, that resample
counts as "not within the budget" (infinite), which widens the interval upwards as it should.

Verdicts: **confirmed** when the interval lies wholly on the paper's side, **contradicted** when it lies
wholly on the other side, **not confirmed** otherwise (the data cannot tell at this many seeds).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from vdtutorial.experiments.curves import CONFIDENCE, moving_average, record_window, smooth_window
from vdtutorial.runner.rows import read_rows, results_file

#: Bootstrap resamples for the steps-to-reach interval.
BOOTSTRAP_SAMPLES = 2000
#: Seed of the bootstrap's generator: the same rows always give the same interval.
BOOTSTRAP_SEED = 0


@dataclass(frozen=True)
class Claim:
    """One sentence of the paper, as a comparison: ``a`` against ``b`` (curve labels) on ``measure``
    ("final", "auc" or "steps_to_reach"), expected ``a > b`` (``direction`` +1) or ``a < b`` (-1). For
    "steps_to_reach", the claim is that ``a`` reaches ``b``'s final level within ``fraction`` of the
    budget."""

    figure: str
    text: str
    measure: str
    a: str
    b: str
    direction: int = 1
    fraction: float | None = None


#: The paper's claims about its figures (Section V-A/B), per experiment.
CLAIMS: dict[str, tuple[Claim, ...]] = {
    "fig4": (
        Claim("fig4", "VD ends above L2", "final", "VD", "L2"),
        Claim("fig4", "VD learns faster than L2 (area under the curve)", "auc", "VD", "L2"),
        Claim("fig4", "VD ends above no pre-training", "final", "VD", "no pre-training"),
        Claim("fig4", "VD learns faster than no pre-training (area under the curve)", "auc", "VD", "no pre-training"),
        Claim("fig4", "VD ends above the IK expert", "final", "VD", "IK expert"),
        Claim("fig4", "VD reaches L2's final level within a quarter of the budget", "steps_to_reach", "VD", "L2",
              fraction=0.25),
    ),
    "fig5": tuple(
        claim for n in (2000, 4000, 8000) for claim in (
            Claim("fig5", f"VD ends above L2 with {n} demonstrations", "final", f"VD, {n} demos", f"L2, {n} demos"),
            Claim("fig5", f"VD learns faster than L2 with {n} demonstrations (AUC)", "auc", f"VD, {n} demos",
                  f"L2, {n} demos"))
    ) + (Claim("fig5", "VD with 2000 demonstrations ends at least as high as L2 with 8000", "final",
               "VD, 2000 demos", "L2, 8000 demos"),),
    "fig6": tuple(
        claim for s in ("0.05", "0.25", "0.5") for claim in (
            Claim("fig6", f"VD ends above L2 at Sigma = {s}", "final", f"VD, Sigma={s}", f"L2, Sigma={s}"),
            Claim("fig6", f"VD learns faster than L2 at Sigma = {s} (AUC)", "auc", f"VD, Sigma={s}", f"L2, Sigma={s}"))
    ),
    "fig7": (
        Claim("fig7", "VD ends above L2 (grasping)", "final", "VD", "L2"),
        Claim("fig7", "VD learns faster than L2 (grasping, AUC)", "auc", "VD", "L2"),
        Claim("fig7", "VD stays below the IK expert after the budget", "final", "VD", "IK expert", direction=-1),
        Claim("fig7", "L2 stays below the IK expert after the budget", "final", "L2", "IK expert", direction=-1),
    ),
}


def per_run(rows: list[dict], metric: str) -> dict[str, dict]:
    """Rows grouped by label: ``{"steps": (T,), "values": (seeds, T)}`` for learning curves, and for the
    expert (one row per measured episode) ``{"values": (episodes,)}``."""
    groups: dict[str, dict] = {}
    for row in rows:
        groups.setdefault(row["label"], {"method": row["method"], "runs": {}})["runs"].setdefault(row["seed"], []).append(row)
    out = {}
    for label, group in groups.items():
        if group["method"] == "expert":
            out[label] = {"values": np.array([r[metric] for run in group["runs"].values() for r in run], dtype=float)}
            continue
        runs = [sorted(run, key=lambda r: r["iteration"]) for run in group["runs"].values()]
        length = min(len(run) for run in runs)
        out[label] = {"steps": np.array([r["env_steps"] for r in runs[0][:length]], dtype=float),
                      "values": np.array([[r[metric] for r in run[:length]] for run in runs], dtype=float)}
    return out


def run_summaries(group: dict, measure: str, window: int) -> np.ndarray:
    """One number per run (per episode for the expert, whose level does not change): the final level or the AUC."""
    values = group["values"]
    if values.ndim == 1:
        return values
    if measure == "final":
        return values[:, -window:].mean(axis=1)
    return values.mean(axis=1)


def welch_interval(a, b, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """mean(a) - mean(b) and its Welch t interval. NaN bounds when either side has fewer than two values."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    diff = float(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return diff, math.nan, math.nan
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = math.sqrt(va + vb)
    if se == 0:
        return diff, diff, diff
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    half = stats.t.ppf((1 + confidence) / 2, dof) * se
    return diff, diff - half, diff + half


def _first_reach(steps: np.ndarray, curve: np.ndarray, level: float) -> float:
    hits = np.flatnonzero(curve >= level)
    return float(steps[hits[0]]) if len(hits) else math.inf


def steps_to_reach_interval(a: dict, b: dict, window: int, confidence: float = CONFIDENCE,
                            samples: int = BOOTSTRAP_SAMPLES, seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float]:
    """First step at which ``a``'s seed-mean smoothed curve reaches ``b``'s final level (its seed-mean
    smoothed end point), with a percentile bootstrap interval over seeds (``inf``: not reached)."""
    smooth_a, smooth_b = moving_average(a["values"], window), moving_average(b["values"], window)

    def estimate(ia, ib) -> float:
        return _first_reach(a["steps"], smooth_a[ia].mean(axis=0), smooth_b[ib, -1].mean())

    rng = np.random.default_rng(seed)
    na, nb = len(smooth_a), len(smooth_b)
    point = estimate(np.arange(na), np.arange(nb))
    boot = np.array([estimate(rng.integers(na, size=na), rng.integers(nb, size=nb)) for _ in range(samples)])
    tail = (1 - confidence) / 2
    low, high = np.quantile(boot, [tail, 1 - tail], method="inverted_cdf")
    return point, float(low), float(high)


def verdict(low: float, high: float, direction: int, threshold: float = 0.0) -> str:
    """Where the interval lies relative to ``threshold``, read in the claim's direction."""
    if math.isnan(low) or math.isnan(high):
        return "not confirmed"
    if direction > 0:
        return "confirmed" if low > threshold else "contradicted" if high < threshold else "not confirmed"
    return "confirmed" if high < threshold else "contradicted" if low > threshold else "not confirmed"


def claim_effects(name: str, rows: list[dict], metric: str, window: int | None = None,
                  confidence: float = CONFIDENCE) -> list[dict]:
    """Every claim of experiment ``name`` whose curves are in ``rows``: estimate, interval, verdict, with
    curves smoothed over ``window`` iterations (default :func:`~vdtutorial.experiments.curves.smooth_window`).
    Claims about curves the run did not make (e.g. no expert line) are left out."""
    window = smooth_window() if window is None else window
    groups = per_run(rows, metric)
    results = []
    for claim in CLAIMS.get(name, ()):
        if claim.a not in groups or claim.b not in groups:
            continue
        a, b = groups[claim.a], groups[claim.b]
        if claim.measure == "steps_to_reach":
            budget_steps = float(a["steps"][-1])
            estimate, low, high = steps_to_reach_interval(a, b, window, confidence)
            limit = claim.fraction * budget_steps
            # "within the fraction" means fewer steps than the limit: read as a < limit
            result_verdict = verdict(low - limit, high - limit, -1)
            unit, extra = "env steps", {"budget_steps": budget_steps, "limit_steps": limit}
        else:
            sa, sb = run_summaries(a, claim.measure, window), run_summaries(b, claim.measure, window)
            estimate, low, high = welch_interval(sa, sb, confidence)
            result_verdict = verdict(low, high, claim.direction)
            unit = f"{metric} per iteration ({'last %d iterations' % window if claim.measure == 'final' else 'mean over the run'})"
            extra = {"mean_a": float(sa.mean()), "mean_b": float(sb.mean()), "n_a": len(sa), "n_b": len(sb)}
        results.append({**asdict(claim), "estimate": estimate, "low": low, "high": high, "confidence": confidence,
                        "unit": unit, "verdict": result_verdict, **extra})
    return results


def _steps(x: float) -> str:
    """An env-step count for the table: three significant digits, or "not reached" for ``inf``."""
    return "not reached" if math.isinf(x) else f"{x:.3g}"


def claim_table(effects: list[dict]) -> str:
    """The claims as a Markdown table (the claim tables of docs/results.md are generated by this)."""
    lines = ["| claim | measure | effect (95% interval) | verdict |", "|---|---|---|---|"]
    for e in effects:
        if e["measure"] == "steps_to_reach":
            unit = "" if math.isinf(e["estimate"]) else " steps"
            effect = (f"{_steps(e['estimate'])}{unit} ({_steps(e['low'])} to {_steps(e['high'])}); "
                      f"limit {_steps(e['limit_steps'])}")
        else:
            effect = f"{e['estimate']:+.2f} ({e['low']:+.2f} to {e['high']:+.2f})"
        lines.append(f"| {e['text']} | {e['measure']} | {effect} | **{e['verdict']}** |")
    return "\n".join(lines)


def write_claims(folder: str | Path) -> str:
    """Recompute the claims of the experiment in ``folder`` (``NAME.csv.gz`` and ``NAME.json``) from its rows,
    store them in the JSON record's summary, and return them as a Markdown table: docs/results.md quotes
    these tables (``python -m vdtutorial claims FOLDER`` prints them)."""
    folder = Path(folder)
    record_path = next(folder.glob("*.json"))
    record = json.loads(record_path.read_text())
    rows = read_rows(results_file(folder, record['experiment']))
    effects = claim_effects(record["experiment"], rows, record["metric"], record_window(record))
    record.setdefault("summary", {})["claims"] = effects
    record_path.write_text(json.dumps(record, indent=1, default=str))
    return claim_table(effects)
