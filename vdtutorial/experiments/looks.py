"""Verdicts on a comparison whose seeds were added after its result had been looked at.

An experiment runs its seeds, someone reads the verdicts, and more seeds are run for the comparison that came
closest. Testing all the seeds as if they had been planned from the start lets that choice in: a difference that
happens to look promising at the first look gets a second chance that the others never had. The record of such an
experiment lists its looks (``looks``: the seeds each look added per curve), and a claim whose two curves both
got seeds at the second look is judged with a **two-stage inverse-normal combination**:

1. stage 1 is the seeds of the first look, stage 2 the seeds added at the second, alone: two independent sets;
2. each stage gives Welch's one-sided p-value in the claim's direction, turned into a normal score
   ``z_k = Phi^-1(1 - p_k)``;
3. the score of the second look is ``(z_1 + z_2) / sqrt(2)``: equal weights, fixed whatever the stages' sizes,
   so that choosing how many seeds to add after seeing stage 1 cannot bend the combination (under no difference it
   is standard normal whatever stage 2's size);
4. the claim's p-value is that of the larger of the two looks' scores, in absolute value (a Pocock-type rule:
   one threshold for both looks): the chance, with no difference, that either look shows a score as far from
   zero. The two scores correlate by ``1/sqrt(2)``; that p-value enters the figure's Holm correction like any
   other, and the verdict stands only if it passes there and the interval over all seeds agrees.

A claim with only one curve extended (the other's seeds all from the first look) has no independent second stage:
it is judged on its first look's seeds. So is a steps-to-reach claim, whose bootstrap has no stage-wise p-value.

Taught in appendix A5.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize, stats

#: The combination's weights of the two stages: equal, and fixed before any look.
STAGE_WEIGHTS = (math.sqrt(0.5), math.sqrt(0.5))
#: How the record's verdict of an extended comparison is computed, in words (records and pages quote it).
RULE = (
    "two-stage inverse-normal combination (equal weights) of the stages' one-sided Welch p-values; the "
    "claim's p-value is the Pocock-type one of the larger of the two looks' scores"
)


def looks_of(record: dict) -> list[dict[str, list[int]]] | None:
    """The seeds each look of a record added, per curve label (``record["looks"]``), or None for an experiment
    whose seeds were all run before anyone looked."""
    looks = record.get("looks")
    if not looks:
        return None
    if len(looks) != 2:
        raise ValueError(f"the sequential rule covers two looks; the record has {len(looks)}")
    return [{label: list(seeds) for label, seeds in look["seeds"].items()} for look in looks]


def stages(a: str, b: str, looks) -> tuple[str, list]:
    """How the claim of curve ``a`` against curve ``b`` uses the looks: ``("all", [])`` without looks or when
    neither curve got seeds at the second look; ``("two", [(seeds_a, seeds_b), (seeds_a, seeds_b)])`` when both
    did; ``("first", [(seeds_a, seeds_b)])`` when only one did."""
    if not looks or (a not in looks[1] and b not in looks[1]):
        return "all", []
    first = (looks[0].get(a, []), looks[0].get(b, []))
    if a in looks[1] and b in looks[1]:
        return "two", [first, (looks[1][a], looks[1][b])]
    return "first", [first]


def pocock_boundary(alpha: float = 0.05, correlation: float = STAGE_WEIGHTS[0]) -> float:
    """The one threshold ``c`` for |score| at both looks such that, with no difference, either look crosses it
    with probability ``alpha`` (two-sided)."""
    return float(optimize.brentq(lambda c: max_score_p_value(c, correlation) - alpha, 1.0, 6.0, xtol=1e-10))


def max_score_p_value(score: float, correlation: float = STAGE_WEIGHTS[0]) -> float:
    """P(max(|Z_1|, |Z_2|) >= ``score``) for standard normal Z_1, Z_2 with ``correlation``: the two-sided p-value
    of the larger of two looks' scores."""
    inside = stats.multivariate_normal(mean=[0.0, 0.0], cov=[[1.0, correlation], [correlation, 1.0]]).cdf(
        [score, score], lower_limit=[-score, -score]
    )
    return float(min(1.0, max(0.0, 1.0 - inside)))


def two_look_test(stage_a: list, stage_b: list, direction: int) -> dict:
    """The two-stage test of "mean(a) - mean(b) has sign ``direction``" from the per-seed numbers of each stage
    (``stage_a[k]``, ``stage_b[k]``: stage k's values): each stage's estimate and one-sided Welch p, the looks'
    scores, the claim's two-sided p-value and the Pocock threshold it is measured against."""
    side = "greater" if direction > 0 else "less"
    one_sided = [
        float(stats.ttest_ind(a, b, equal_var=False, alternative=side).pvalue) for a, b in zip(stage_a, stage_b)
    ]
    z = [float(stats.norm.isf(p)) for p in one_sided]
    combined = STAGE_WEIGHTS[0] * z[0] + STAGE_WEIGHTS[1] * z[1]
    return {
        "rule": RULE,
        "stage_estimates": [float(np.mean(a) - np.mean(b)) for a, b in zip(stage_a, stage_b)],
        "stage_seeds": [[len(a), len(b)] for a, b in zip(stage_a, stage_b)],
        "stage_p_one_sided": one_sided,
        "look_scores": [z[0], combined],
        "combined_p_one_sided": float(stats.norm.sf(combined)),
        "p_value": max_score_p_value(max(abs(z[0]), abs(combined))),
        "pocock_threshold": pocock_boundary(),
    }


def looks_table(effects: list[dict]) -> str:
    """The claims of a record judged over two looks (:func:`two_look_test`), as Markdown: each stage's effect, seeds
    and one-sided p, the combined one-sided p, the claim's p-value against Welch's on all seeds at once, and the
    Holm verdict (the results page's table of Fig. 5 is generated by this)."""
    lines = [
        (
            "| claim | metric | measure | stage 1: effect, seeds, one-sided p | stage 2: effect, seeds, one-sided p"
            " | combined one-sided p | claim's p (all seeds at once) | Holm |"
        ),
        "|---|---|---|---|---|---|---|---|",
    ]
    for e in (e for e in effects if isinstance(e.get("looks"), dict)):
        looks = e["looks"]
        stages_text = [
            f"{estimate:+.3g}, {seeds[0]} / {seeds[1]}, {p:.2g}"
            for estimate, seeds, p in zip(looks["stage_estimates"], looks["stage_seeds"], looks["stage_p_one_sided"])
        ]
        lines.append(
            f"| {e['text']} | {e['metric']} | {e['measure']} | {stages_text[0]} | {stages_text[1]} | "
            f"{looks['combined_p_one_sided']:.2g} | {e['p_value']:.2g} ({e['p_value_all_seeds_at_once']:.2g}) "
            f"| {e['holm_verdict']} |"
        )
    return "\n".join(lines)
