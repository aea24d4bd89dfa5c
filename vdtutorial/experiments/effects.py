"""The paper's claims as effect sizes with 95% intervals over seeds, and a verdict for each.

A claim compares two methods; for every claim of Section V (Figs. 4-7) this module measures, per run:

final level
    each run's mean metric over its last ``window`` iterations (the smoothed curve's end point);
area under the curve (AUC)
    each run's mean metric over all its iterations: how much was achieved along the way, which is
    what "learns faster" means over a fixed budget;
steps to reach
    the first env step at which the first method's seed-mean smoothed curve reaches the second
    method's final level (the paper's "VD overtakes L2's final performance at ~1.25e5 steps").

The first two are differences of means over seeds with Welch's t interval (seeds are the independent, and few,
replicates). The steps-to-reach estimate has no closed form: its interval is a percentile bootstrap over seeds
(``BOOTSTRAP_SAMPLES`` seeded resamples; one that never reaches the level counts as infinite), and below
``MIN_BOOTSTRAP_SEEDS`` seeds per method an exact sign test over the seeds instead, its verdict capped.

Verdicts: **confirmed** when the interval lies wholly on the paper's side, **contradicted** when it lies
wholly on the other side, **not confirmed** otherwise (the data cannot tell at this many seeds), and
**negligible** when it excludes zero but lies wholly within ``MATERIALITY`` of the level compared against (a real
difference too small to matter); beside each, the Holm-corrected verdict and the smallest difference the seeds
could detect (:func:`claim_effects`).

Taught in chapter 07 and appendix A5.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import integrate, optimize, stats

from vdtutorial.experiments.curves import (
    CONFIDENCE,
    PAPER_BUDGET_STEPS,
    PAPER_QUARTER,
    PAPER_REACH_STEPS,
    moving_average,
    smooth_window,
)
from vdtutorial.experiments.looks import stages, two_look_test
from vdtutorial.experiments.measures import MEASURES, measures_of, value
from vdtutorial.methods import method

#: Bootstrap resamples for the steps-to-reach interval.
BOOTSTRAP_SAMPLES = 2000
#: Seed of the bootstrap's generator: the same rows always give the same interval.
BOOTSTRAP_SEED = 0
#: Fewest seeds per method for a steps-to-reach verdict from the bootstrap. With n seeds a method has only
#: C(2n - 1, n) distinct resamples (10 at n = 3, 35 at 4, 126 at 5), so the bootstrap's tail shares, and the p-values
#: read from them, are artefacts of a handful of resamples: at 3 seeds with every seed late, p prints as "< 0.0005"
#: where the sign test over the 3 seeds gives 0.25. From 5 seeds on there are over a hundred; below, the sign test
#: decides, and since it cannot reach p < 0.05 with fewer than 6 seeds, such a verdict is capped at "not confirmed".
MIN_BOOTSTRAP_SEEDS = 5
#: Power at which the detectable difference is found.
POWER = 0.8
#: A difference smaller than this share of the level compared against (the second method's, or the expert's) is
#: immaterial, on every measure in its own units: a row whose whole interval lies within it excludes any material
#: effect either way, and when that interval also excludes zero the verdict is "negligible", neither "confirmed" nor
#: "contradicted". The level compared against, not the expert's, because Figs. 5 and 6 ran no expert; near the
#: expert (VD, L2) the two are within a few percent of each other.
MATERIALITY = 0.05


@dataclass(frozen=True)
class Claim:
    """One sentence of the paper, as a comparison: ``a`` against ``b`` (curve labels) on ``measure``
    ("final", "auc" or "steps_to_reach"), expected ``a > b`` (``direction`` +1) or ``a < b`` (-1). For
    "steps_to_reach", the claim is that ``a`` reaches ``b``'s final level within ``fraction`` of the
    budget. ``same_runs`` names the figure whose claim this one restates on the very same runs (Figs. 5 and 6 reuse
    Fig. 4's 8000-demonstration, Sigma 0.5 runs): such rows are one comparison, not independent evidence."""

    figure: str
    text: str
    measure: str
    a: str
    b: str
    direction: int = 1
    fraction: float | None = None
    same_runs: str | None = None


#: The paper's headline as one claim: VD reaches L2's final level by 1.25e5 of 3e5 steps (42% of the budget). Its
#: "less than one quarter" is a stricter limit on the same quantity, so a second row would only restate the first:
#: it is reported beside it (``quarter_verdict``), not tested as a claim of its own.
REACH_CLAIM = (
    "VD reaches L2's final level within 42% of the budget (paper: 1.25e5 of 3e5 steps; "
    "'less than one quarter' noted beside it)"
)
#: The paper's claims about its figures (Section V-A/B), per experiment.
CLAIMS: dict[str, tuple[Claim, ...]] = {
    "fig4": (
        Claim("fig4", "VD ends above L2", "final", "VD", "L2"),
        Claim("fig4", "VD learns faster than L2 (area under the curve)", "auc", "VD", "L2"),
        Claim("fig4", "VD ends above no pre-training", "final", "VD", "no pre-training"),
        Claim("fig4", "VD learns faster than no pre-training (area under the curve)", "auc", "VD", "no pre-training"),
        Claim("fig4", "VD ends above the IK expert", "final", "VD", "IK expert"),
        Claim("fig4", REACH_CLAIM, "steps_to_reach", "VD", "L2", fraction=PAPER_REACH_STEPS / PAPER_BUDGET_STEPS),
    ),
    "fig5": tuple(
        claim
        for n in (2000, 4000, 8000)
        for claim in (
            Claim(
                "fig5",
                f"VD ends above L2 with {n} demonstrations",
                "final",
                f"VD, {n} demos",
                f"L2, {n} demos",
                same_runs="Fig. 4" if n == 8000 else None,
            ),
            Claim(
                "fig5",
                f"VD learns faster than L2 with {n} demonstrations (AUC)",
                "auc",
                f"VD, {n} demos",
                f"L2, {n} demos",
                same_runs="Fig. 4" if n == 8000 else None,
            ),
        )
    )
    + (
        Claim(
            "fig5",
            "VD with 2000 demonstrations ends at least as high as L2 with 8000",
            "final",
            "VD, 2000 demos",
            "L2, 8000 demos",
        ),
    ),
    "fig6": tuple(
        claim
        for s in ("0.05", "0.25", "0.5")
        for claim in (
            Claim(
                "fig6",
                f"VD ends above L2 at Sigma = {s}",
                "final",
                f"VD, Sigma={s}",
                f"L2, Sigma={s}",
                same_runs="Fig. 4" if s == "0.5" else None,
            ),
            Claim(
                "fig6",
                f"VD learns faster than L2 at Sigma = {s} (AUC)",
                "auc",
                f"VD, Sigma={s}",
                f"L2, Sigma={s}",
                same_runs="Fig. 4" if s == "0.5" else None,
            ),
        )
    ),
    "fig7": (
        Claim("fig7", "VD ends above L2 (grasping)", "final", "VD", "L2"),
        Claim("fig7", "VD learns faster than L2 (grasping, AUC)", "auc", "VD", "L2"),
        Claim("fig7", "VD stays below the IK expert after the budget", "final", "VD", "IK expert", direction=-1),
        Claim("fig7", "L2 stays below the IK expert after the budget", "final", "L2", "IK expert", direction=-1),
    ),
}


def per_run(rows: list[dict], metric: str) -> dict[str, dict]:
    """Rows grouped by label, each row's ``metric`` (a column or a derived measure,
    :func:`~vdtutorial.experiments.measures.value`): ``{"steps": (T,), "values": (seeds, T)}`` for learning
    curves, and for the expert (one row per measured episode) ``{"values": (episodes,)}``."""
    groups: dict[str, dict] = {}
    for row in rows:
        groups.setdefault(row["label"], {"method": row["method"], "runs": {}})["runs"].setdefault(
            row["seed"], []
        ).append(row)
    out = {}
    for label, group in groups.items():
        if group["method"] == "expert":
            out[label] = {
                "values": np.array([value(r, metric) for run in group["runs"].values() for r in run], dtype=float)
            }
            continue
        runs = [sorted(run, key=lambda r: r["iteration"]) for run in group["runs"].values()]
        length = min(len(run) for run in runs)
        out[label] = {
            "steps": np.array([r["env_steps"] for r in runs[0][:length]], dtype=float),
            "values": np.array([[value(r, metric) for r in run[:length]] for run in runs], dtype=float),
            "seeds": list(group["runs"]),
        }
    return out


def of_seeds(group: dict, seeds) -> dict:
    """A learning-curve group of :func:`per_run` cut to the runs of ``seeds`` (an expert's group as it is)."""
    if group["values"].ndim == 1:
        return group
    keep = [group["seeds"].index(seed) for seed in seeds]
    return {**group, "values": group["values"][keep], "seeds": list(seeds)}


def run_summaries(group: dict, measure: str, window: int) -> np.ndarray:
    """One number per run (per episode for the expert, whose level does not change): the final level or the AUC."""
    values = group["values"]
    if values.ndim == 1:
        return values
    if measure == "final":
        return values[:, -window:].mean(axis=1)
    return values.mean(axis=1)


def _welch(a, b) -> tuple[float, float, float]:
    """mean(a) - mean(b), its standard error and the Welch-Satterthwaite degrees of freedom (NaN for the
    last two when either side has fewer than two values)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    diff = float(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return diff, math.nan, math.nan
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    if va + vb == 0:
        return diff, 0.0, math.nan
    return diff, math.sqrt(va + vb), (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))


def welch_interval(a, b, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """mean(a) - mean(b) and its Welch t interval. NaN bounds when either side has fewer than two values."""
    diff, se, dof = _welch(a, b)
    if math.isnan(se):
        return diff, math.nan, math.nan
    if se == 0:
        return diff, diff, diff
    half = stats.t.ppf((1 + confidence) / 2, dof) * se
    return diff, diff - half, diff + half


def welch_p_value(a, b) -> float:
    """Two-sided p-value of Welch's t-test of mean(a) = mean(b) (against the expert's episodes too). NaN when
    either side has fewer than two values; 0 or 1 when neither side varies."""
    diff, se, dof = _welch(a, b)
    if math.isnan(se):
        return math.nan
    if se == 0:
        return 1.0 if diff == 0 else 0.0
    return float(2 * stats.t.sf(abs(diff) / se, dof))


def _first_reach(steps: np.ndarray, curve: np.ndarray, level: float, better: int = 1) -> float:
    hits = np.flatnonzero(better * (curve - level) >= 0)
    return float(steps[hits[0]]) if len(hits) else math.inf


def _bootstrap_steps_to_reach(
    a: dict, b: dict, window: int, better: int, samples: int, seed: int
) -> tuple[float, np.ndarray]:
    """The steps-to-reach point estimate and its ``samples`` bootstrap resamples over seeds."""
    smooth_a, smooth_b = moving_average(a["values"], window), moving_average(b["values"], window)

    def estimate(ia, ib) -> float:
        return _first_reach(a["steps"], smooth_a[ia].mean(axis=0), smooth_b[ib, -1].mean(), better)

    rng = np.random.default_rng(seed)
    na, nb = len(smooth_a), len(smooth_b)
    point = estimate(np.arange(na), np.arange(nb))
    return point, np.array([estimate(rng.integers(na, size=na), rng.integers(nb, size=nb)) for _ in range(samples)])


def _percentile_interval(boot: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = (1 - confidence) / 2
    low, high = np.quantile(boot, [tail, 1 - tail], method="inverted_cdf")
    return float(low), float(high)


def steps_to_reach_interval(
    a: dict,
    b: dict,
    window: int,
    confidence: float = CONFIDENCE,
    samples: int = BOOTSTRAP_SAMPLES,
    seed: int = BOOTSTRAP_SEED,
    better: int = 1,
) -> tuple[float, float, float]:
    """First step at which ``a``'s seed-mean smoothed curve reaches ``b``'s final level (its seed-mean
    smoothed end point; "reaches": at or above it, or at or below it for a measure where lower is
    ``better``), with a percentile bootstrap interval over seeds (``inf``: not reached)."""
    point, boot = _bootstrap_steps_to_reach(a, b, window, better, samples, seed)
    return point, *_percentile_interval(boot, confidence)


def seeds_within(a: dict, b: dict, window: int, limit: float, better: int = 1) -> int:
    """How many of ``a``'s seeds, each on its own smoothed curve, reach ``b``'s final level (seed-mean smoothed end
    point) by ``limit`` env steps: the count behind the sign test of a steps-to-reach claim with few seeds."""
    smooth_a, level = moving_average(a["values"], window), moving_average(b["values"], window)[:, -1].mean()
    return sum(_first_reach(a["steps"], curve, level, better) <= limit for curve in smooth_a)


def bootstrap_p_value(boot: np.ndarray, limit: float) -> float:
    """Two-sided p-value of "steps to reach = ``limit``" from the bootstrap resamples ``boot``: twice the
    smaller share of resamples on either side of it (at most 1), the test the percentile interval inverts."""
    return float(min(1.0, 2 * min(np.mean(boot <= limit), np.mean(boot >= limit))))


def holm_rejections(p_values: list[float], alpha: float = 1 - CONFIDENCE) -> list[bool]:
    """Holm's step-down procedure: sort the p-values, reject the k-th smallest while it is below
    alpha / (m - k + 1), and stop at the first that is not. NaN p-values are never rejected."""
    order = sorted(range(len(p_values)), key=lambda i: (math.isnan(p_values[i]), p_values[i]))
    rejected = [False] * len(p_values)
    for rank, i in enumerate(order):
        if math.isnan(p_values[i]) or p_values[i] >= alpha / (len(p_values) - rank):
            break
        rejected[i] = True
    return rejected


def _power(shift: float, critical: float, dof: float) -> float:
    """P(|T| > critical) for T noncentral t with ``dof`` degrees of freedom and noncentrality ``shift``. scipy's
    ``nct`` returns NaN for the few degrees of freedom and far tails that Holm's small levels reach: there the
    probability is integrated over the chi-square of the t's denominator instead."""
    power = stats.nct.sf(critical, dof, shift) + stats.nct.cdf(-critical, dof, shift)
    if math.isfinite(power):
        return float(power)

    def density(v: float) -> float:
        scale = critical * math.sqrt(v / dof)
        return (stats.norm.sf(scale - shift) + stats.norm.cdf(-scale - shift)) * stats.chi2.pdf(v, dof)

    return float(integrate.quad(density, 0, math.inf, limit=200)[0])


def detectable_difference(standard_error: float, dof: float, alpha: float, power: float = POWER) -> float:
    """The smallest difference that the verdict's own test (two-sided Welch t at level ``alpha``, the difference's
    ``standard_error`` and Welch-Satterthwaite ``dof`` as the seeds measured them) finds with probability ``power``.
    NaN when the spread is unknown (fewer than two values on a side)."""
    if not (math.isfinite(standard_error) and math.isfinite(dof)) or standard_error == 0:
        return math.nan
    critical = stats.t.ppf(1 - alpha / 2, dof)
    high = 1.0
    while _power(high, critical, dof) < power:
        high *= 2
    shift = optimize.brentq(lambda x: _power(x, critical, dof) - power, 0.0, high, xtol=1e-6)
    return float(shift * standard_error)


def verdict(low: float, high: float, direction: int, threshold: float = 0.0, material: float = 0.0) -> str:
    """Where the interval lies relative to ``threshold``, read in the claim's direction: "negligible" when it lies on
    one side but within ``material`` of the threshold (a difference, if real, too small to matter)."""
    if math.isnan(low) or math.isnan(high):
        return "not confirmed"
    if (low > threshold or high < threshold) and threshold - material < low and high < threshold + material:
        return "negligible"
    if direction > 0:
        return "confirmed" if low > threshold else "contradicted" if high < threshold else "not confirmed"
    return "confirmed" if high < threshold else "contradicted" if low > threshold else "not confirmed"


def claim_effects(
    name: str,
    rows: list[dict],
    metric: str,
    window: int | None = None,
    confidence: float = CONFIDENCE,
    claims: tuple[Claim, ...] | None = None,
    looks: list[dict] | None = None,
    primary: tuple[str, ...] | None = None,
) -> list[dict]:
    """Every claim of experiment ``name`` (``CLAIMS[name]``, or ``claims``: an experiment whose questions depend
    on its results, like the beyond experiment's "best hand-set Sigma") whose curves are in ``rows``, on every
    measure of an experiment with paper metric ``metric`` (:func:`~vdtutorial.experiments.measures.measures_of`):
    estimate, interval, p-value, verdict, Holm verdict and detectable difference, with curves smoothed over
    ``window`` iterations (default :func:`~vdtutorial.experiments.curves.smooth_window`). Claims about curves the
    run did not make (e.g. no expert line) are left out.

    Every claim is tested on each measure of :mod:`~vdtutorial.experiments.measures` (the paper's metric, the
    success rate, the steps per trajectory), read in the measure's better direction ("VD ends above L2" means
    fewer steps per trajectory on that measure). The paper's metric is the **primary** measure: its claims are one
    family; the claims on the two other measures, chosen after the paper, are a second family, both measures
    together. Each family tests several claims at 95% each, so by chance alone some would pass: beside each verdict
    stands the **Holm** verdict, the same claims tested with Holm's step-down correction over the family
    (family-wise error 5%; the p-value of a difference of means is Welch's two-sided one, that of steps to reach
    the bootstrap's two-sided share of resamples on the far side of the limit, or with fewer than
    ``MIN_BOOTSTRAP_SEEDS`` seeds the two-sided sign test of the seeds within the limit, whose verdict is capped at
    "not confirmed"). The **detectable difference** is what a reader can use from a "not confirmed": the smallest
    difference the seeds at hand would find with 80% power under the verdict's own test (Welch, with the measured
    spreads) at Holm's strictest level, 5% over the family's size (:func:`detectable_difference`). A row whose whole
    interval lies within ``MATERIALITY`` (5%) of the level compared against says "no material effect": the seeds
    already exclude any difference worth the name, either way; if that interval also excludes zero, the verdict is
    "negligible" (significant, but immaterial) rather than "confirmed" or "contradicted".

    ``looks``: the seeds each look added per curve, for an experiment extended after its result was seen
    (:func:`~vdtutorial.experiments.looks.looks_of`); a claim on extended curves is then judged by the sequential
    rule of :mod:`~vdtutorial.experiments.looks`.

    ``primary``: the claims (by their words) a pre-registered plan made its primary family
    (:mod:`~vdtutorial.experiments.plans`): only they form the primary family, each marked ``planned``, and the
    record's other claims on the paper's metric join the secondary family, reported beside them.
    """
    window = smooth_window() if window is None else window
    results = []
    for measure in measures_of(metric):
        groups = per_run(rows, measure)
        for claim in CLAIMS.get(name, ()) if claims is None else claims:
            if claim.a not in groups or claim.b not in groups:
                continue
            first = measure == metric and (primary is None or claim.text in primary)
            results.append(
                {
                    **_claim_effect(claim, groups, measure, window, confidence, looks),
                    "family": "primary" if first else "secondary",
                    **({"planned": True} if first and primary is not None else {}),
                }
            )
    for family in ("primary", "secondary"):
        table = [e for e in results if e["family"] == family]
        for effect, rejected in zip(table, holm_rejections([e["p_value"] for e in table], 1 - confidence)):
            effect["holm_verdict"] = effect["verdict"] if rejected else "not confirmed"
            if effect["measure"] != "steps_to_reach":  # at Holm's strictest level: alpha over the family's size
                effect["detectable"] = detectable_difference(
                    effect["standard_error"], effect["dof"], (1 - confidence) / len(table)
                )
    return results


def _claim_effect(
    claim: Claim, groups: dict, measure: str, window: int, confidence: float, looks: list[dict] | None = None
) -> dict:
    """One claim on one measure (see :func:`claim_effects`); on curves extended after a look, with the sequential
    rule of :mod:`~vdtutorial.experiments.looks` (or on the first look's seeds where it has no second stage)."""
    a, b = groups[claim.a], groups[claim.b]
    kind, seeds = stages(claim.a, claim.b, looks)
    why = "no independent second stage"
    if kind == "two" and claim.measure == "steps_to_reach":
        kind, seeds, why = "first", seeds[:1], "no stage-wise p-value for steps to reach"
    if kind == "first":
        effect = _claim_effect(
            claim, {claim.a: of_seeds(a, seeds[0][0]), claim.b: of_seeds(b, seeds[0][1])}, measure, window, confidence
        )
        return {**effect, "looks": f"first look's seeds: {why}"}
    effect = _plain_claim_effect(claim, a, b, measure, window, confidence)
    if kind == "all":
        return effect
    staged = [
        [run_summaries(of_seeds(group, stage[k]), claim.measure, window) for stage in seeds]
        for k, group in ((0, a), (1, b))
    ]
    test = two_look_test(staged[0], staged[1], claim.direction * MEASURES[measure].better)
    passed = test["p_value"] < 1 - confidence
    return {
        **effect,
        "p_value_all_seeds_at_once": effect["p_value"],
        "p_value": test["p_value"],
        "verdict": effect["verdict"] if passed else "not confirmed",
        "looks": test,
    }


def _plain_claim_effect(claim: Claim, a: dict, b: dict, measure: str, window: int, confidence: float) -> dict:
    """One claim on one measure, every seed of the two groups tested at once."""
    better = MEASURES[measure].better
    if claim.measure == "steps_to_reach":
        budget_steps = float(a["steps"][-1])
        estimate, boot = _bootstrap_steps_to_reach(a, b, window, better, BOOTSTRAP_SAMPLES, BOOTSTRAP_SEED)
        low, high = _percentile_interval(boot, confidence)
        limit = claim.fraction * budget_steps
        result_verdict, p_value, extra = _reach_test(a, b, window, better, boot, (low, high), limit)
        extra.update(budget_steps=budget_steps, limit_steps=limit, n_a=len(a["values"]), n_b=len(b["values"]))
        if claim.fraction > PAPER_QUARTER:  # the paper's stricter reading, beside the claim
            quarter = PAPER_QUARTER * budget_steps
            extra.update(
                quarter_limit_steps=quarter,
                quarter_verdict=_reach_test(a, b, window, better, boot, (low, high), quarter)[0],
            )
        unit = "env steps"
    else:
        sa, sb = run_summaries(a, claim.measure, window), run_summaries(b, claim.measure, window)
        estimate, low, high = welch_interval(sa, sb, confidence)
        material = MATERIALITY * abs(float(sb.mean()))
        result_verdict = verdict(low, high, claim.direction * better, material=material)
        p_value = welch_p_value(sa, sb)
        over = f"last {window} iterations" if claim.measure == "final" else "mean over the run"
        unit = f"{measure} per iteration ({over})"
        _, standard_error, dof = _welch(sa, sb)
        extra = {
            "mean_a": float(sa.mean()),
            "mean_b": float(sb.mean()),
            "n_a": len(sa),
            "n_b": len(sb),
            "n_b_counts": "episodes" if b["values"].ndim == 1 else "seeds",
            "standard_error": standard_error,
            "dof": dof,
            "material": material,
            "no_material_effect": bool(-material < low and high < material),
        }
    return {
        **asdict(claim),
        "metric": measure,
        "estimate": estimate,
        "low": low,
        "high": high,
        "confidence": confidence,
        "unit": unit,
        "p_value": p_value,
        "verdict": result_verdict,
        **extra,
    }


def _reach_test(
    a: dict, b: dict, window: int, better: int, boot: np.ndarray, interval: tuple[float, float], limit: float
) -> tuple[str, float, dict]:
    """Verdict, p-value and test of "``a`` reaches ``b``'s final level by ``limit`` env steps": the bootstrap's
    (resamples ``boot``, percentile ``interval``), or with fewer than :data:`MIN_BOOTSTRAP_SEEDS` seeds per method
    the sign test over ``a``'s seeds, its verdict capped at "not confirmed"."""
    if min(len(a["values"]), len(b["values"])) < MIN_BOOTSTRAP_SEEDS:
        within = seeds_within(a, b, window, limit, better)
        p_value = float(stats.binomtest(within, len(a["values"])).pvalue)
        return "not confirmed", p_value, {"test": "sign", "seeds_within": within}
    low, high = interval  # "within the limit" means fewer steps than the limit: read as a < limit
    return verdict(low - limit, high - limit, -1), bootstrap_p_value(boot, limit), {"test": "bootstrap"}


def _steps(x: float) -> str:
    """An env-step count for the table: three significant digits, or "not reached" for ``inf``."""
    return "not reached" if math.isinf(x) else f"{x:.3g}"


def _seeds(e: dict) -> str:
    """The seeds a claim rests on: "5" when both methods have the same, "5 / 10" otherwise, and the expert's
    measured episodes named as such ("5 / 125 episodes")."""
    if e.get("n_b_counts") == "episodes":
        return f"{e['n_a']} / {e['n_b']} episodes"
    if isinstance(e.get("looks"), dict):  # two looks: the seeds of each, "10 + 13"
        per_look = [f"{a}" if a == b else f"{a} / {b}" for a, b in e["looks"]["stage_seeds"]]
        return " + ".join(per_look)
    return str(e["n_a"]) if e["n_a"] == e["n_b"] else f"{e['n_a']} / {e['n_b']}"


def _claim_text(e: dict) -> str:
    """A claim's words, the figure whose runs it shares (such rows are one comparison), how seeds added after
    a look were used (:mod:`~vdtutorial.experiments.looks`), whether a plan fixed its test before the runs
    (:mod:`~vdtutorial.experiments.plans`), and whether its curves come from different batches of
    seeds (:mod:`~vdtutorial.experiments.batches`)."""
    looks = e.get("looks")
    return (
        e["text"]
        + (f" (same runs as {e['same_runs']})" if e.get("same_runs") else "")
        + (" (2 looks: sequential rule)" if isinstance(looks, dict) else f" ({looks})" if looks else "")
        + (" (pre-registered)" if e.get("planned") else "")
        + (" (across batches of seeds)" if e.get("across_batches") else "")
    )


def claim_table(effects: list[dict]) -> str:
    """The claims as Markdown, one table per measure (the claim tables of docs/results.md are generated by
    this): effect and 95% interval, two-sided p, verdict, Holm verdict, the seeds behind it and the smallest
    difference those seeds can detect (see the module's docstring)."""
    blocks = []
    for measure in dict.fromkeys(e.get("metric", "successes") for e in effects):
        lines = [
            f"*{MEASURES[measure].label}*: {MEASURES[measure].question}",
            "",
            "| claim | measure | effect (95% interval) | p | verdict | Holm | seeds | detectable |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for e in (e for e in effects if e.get("metric", "successes") == measure):
            if e["measure"] == "steps_to_reach" and e.get("test") == "sign":
                unit = "" if math.isinf(e["estimate"]) else " steps"
                effect = (
                    f"{_steps(e['estimate'])}{unit}; {e['seeds_within']} of {e['n_a']} seeds within the limit "
                    f"{_steps(e['limit_steps'])} (sign test: too few seeds for a verdict)"
                )
            elif e["measure"] == "steps_to_reach":
                unit = "" if math.isinf(e["estimate"]) else " steps"
                effect = (
                    f"{_steps(e['estimate'])}{unit} ({_steps(e['low'])} to {_steps(e['high'])}); "
                    f"limit {_steps(e['limit_steps'])}"
                )
            if "quarter_verdict" in e:
                effect += f"; at a quarter ({_steps(e['quarter_limit_steps'])}): {e['quarter_verdict']}"
            else:
                effect = f"{e['estimate']:+.3g} ({e['low']:+.3g} to {e['high']:+.3g})"
            needed = (
                "-"
                if e["measure"] == "steps_to_reach"
                else f"{e['detectable']:.3g}" + ("; no material effect" if e["no_material_effect"] else "")
            )
            bootstrap_floor = e["p_value"] == 0 and e["measure"] == "steps_to_reach"
            p_value = f"< {1 / BOOTSTRAP_SAMPLES:.0g}" if bootstrap_floor else f"{e['p_value']:.2g}"
            lines.append(
                f"| {_claim_text(e)} | {e['measure']} | {effect} | {p_value} | **{e['verdict']}** | "
                f"{e['holm_verdict']} | {_seeds(e)} | {needed} |"
            )
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)


def claims_overview(records: dict[str, dict], measures: tuple[str, ...] = ("final", "steps_to_reach")) -> str:
    """One Markdown row per claim (of the kinds in ``measures``) of each experiment record (``{"heading": record}``):
    the verdict and the Holm verdict on the paper's metric (the primary measure), the Holm verdicts on the two
    secondary measures (one family), and the seeds; a row on another figure's runs says so (the README's claims
    table is generated by this)."""
    lines = [
        "| figure | claim | paper's metric (primary): verdict / Holm | success rate: Holm (secondary) | "
        "steps per trajectory: Holm (secondary) | seeds |",
        "|---|---|---|---|---|---|",
    ]
    for heading, record in records.items():
        effects = [e for e in record["summary"]["claims"] if e["measure"] in measures]
        by_metric = {(e["text"], e["metric"]): e for e in effects}
        for e in (e for e in effects if e["metric"] == record["metric"]):
            others = [by_metric[(e["text"], m)]["holm_verdict"] for m in measures_of(record["metric"])[1:]]
            lines.append(
                f"| {heading} | {_claim_text(e)} | {e['verdict']} / **{e['holm_verdict']}** | "
                f"{' | '.join(others)} | {_seeds(e)} |"
            )
    return "\n".join(lines)


def demo_seed_of(record: dict) -> int:
    """The draw of the demonstrations a figure's record was pre-trained on (its runs' ``demo_seed``; records made
    before runs had one used the shipped draw, 0)."""
    seeds = {run.get("demo_seed", 0) for run in record["runs"] if method(run["method"]).pretrains}
    if len(seeds) != 1:
        raise ValueError(f"a record pre-trained on {len(seeds)} draws of the data: expected one")
    return seeds.pop()


def draws_table(records: list[dict], measures: tuple[str, ...] = ("final", "auc")) -> str:
    """The claims that several records of one figure share, each record a draw of the demonstrations
    (:func:`demo_seed_of`), side by side as Markdown: per claim on the paper's metric, each draw's effect with its
    95% interval and its Holm verdict (within that record's own family). An effect that holds on one draw only
    rests on that draw of the data, not on the method."""
    heads = [f"demonstrations seed {demo_seed_of(r)}: effect (95% interval), Holm" for r in records]
    by_text = [
        {e["text"]: e for e in r["summary"]["claims"] if e["metric"] == r["metric"] and e["measure"] in measures}
        for r in records
    ]
    lines = ["| claim | " + " | ".join(heads) + " | seeds |", "|---|" + "---|" * len(records) + "---|"]
    for text in (t for t in by_text[0] if all(t in other for other in by_text[1:])):
        cells = [
            f"{e['estimate']:+.3g} ({e['low']:+.3g} to {e['high']:+.3g}), **{e['holm_verdict']}**"
            for e in (table[text] for table in by_text)
        ]
        lines.append(f"| {text} | " + " | ".join(cells) + f" | {' / '.join(_seeds(t[text]) for t in by_text)} |")
    return "\n".join(lines)
