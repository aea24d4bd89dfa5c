"""Tests fixed before their runs: a pre-registered plan's primary claims, and the check that its runs are all there.

Every figure's record tests all its claims on the paper's metric as one family, with Holm's correction over it
(:func:`~vdtutorial.experiments.effects.claim_effects`). A plan written before its runs can fix a narrower test:
the image Fig. 5 at 2000 demonstrations (``docs/plan-ablations-and-image-fig5.md``, section 1) makes one claim,
"VD ends above L2 with 2000 demonstrations" on the final level, its only primary test, at alpha = 0.05 with no
correction, and reports the area under the curve and the secondary measures without deciding on them. Testing the
record as any other would correct that claim over two (final level and area), a rule the plan did not choose.

So a planned experiment's record names its plan (``record["plan"]``, written once by ``python -m vdtutorial
rederive FOLDER --plan NAME``), and every later re-derivation tests the plan's claims as the primary family alone:
with one claim, Holm's verdict is the plain one, as the plan says. The other claims on the paper's metric join the
secondary measures' family, reported with their own Holm verdicts. A plan is applied only to the runs it fixed:
its curves, seeds and budget, every run finished (its stopping rule: no early stop, no extension).

Taught in chapter 10.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Plan:
    """One pre-registered experiment: the ``document`` (relative to the project root) and ``section`` that fix it,
    the ``experiment`` and observation mode (``obs_mode``) it runs, its ``curves`` (labels) with ``seeds`` each, every
    run to ``total_steps`` env steps, and the claims (by their words in
    :data:`~vdtutorial.experiments.effects.CLAIMS`) that form its ``primary`` family on the paper's metric."""

    name: str
    document: str
    section: str
    experiment: str
    obs_mode: str
    curves: tuple[str, ...]
    seeds: tuple[int, ...]
    total_steps: int
    primary: tuple[str, ...]

    @property
    def rule(self) -> str:
        """How the plan's verdict is computed, in words (the record and the pages quote it)."""
        claims = (
            "one primary claim, no Holm correction"
            if len(self.primary) == 1
            else (f"{len(self.primary)} primary claims, Holm over them alone")
        )
        return (
            f"pre-registered ({self.document}, {self.section}): Welch's t, two-sided, 95% interval, on the final "
            f"level; the plan's {claims}; the other claims and measures are reported, not decided on"
        )


#: The plans written before their runs, by name (``rederive --plan NAME``).
PLANS = {
    "image-fig5-n2000": Plan(
        name="image-fig5-n2000",
        document="docs/plan-ablations-and-image-fig5.md",
        section="section 1",
        experiment="fig5",
        obs_mode="rgbd",
        curves=("VD, 2000 demos", "L2, 2000 demos"),
        seeds=tuple(range(15)),
        total_steps=300_000,
        primary=("VD ends above L2 with 2000 demonstrations",),
    ),
}


def plan_named(name: str) -> Plan:
    """The plan called ``name``, or a ValueError naming the plans there are."""
    if name not in PLANS:
        raise ValueError(f"no plan called {name!r}; the pre-registered plans are: {', '.join(sorted(PLANS))}")
    return PLANS[name]


def unmet(plan: Plan, record: dict) -> list[str]:
    """What in an experiment's ``record`` differs from the runs ``plan`` fixed, one line each (empty: the record is
    the plan's, every run finished): another experiment or observation mode, a curve missing or added, a seed
    missing or added, a run short of (or beyond) the budget."""
    problems = []
    if record["experiment"] != plan.experiment:
        problems.append(f"the record is {record['experiment']}'s, the plan runs {plan.experiment}")
    learners = [run for run in record["runs"] if run["method"] != "expert"]
    modes = sorted({run["obs_mode"] for run in learners})
    if modes != [plan.obs_mode]:
        problems.append(f"the runs observe {', '.join(modes)}; the plan's observe {plan.obs_mode}")
    seeds = {label: sorted(run["seed"] for run in learners if run["label"] == label) for label in plan.curves}
    for label in plan.curves:
        missing = sorted(set(plan.seeds) - set(seeds[label]))
        extra = sorted(set(seeds[label]) - set(plan.seeds))
        if missing:
            problems.append(f"{label}: seeds {missing} not finished (the plan runs seeds {list(plan.seeds)})")
        if extra:
            problems.append(f"{label}: seeds {extra} beyond the plan's (no extension)")
    others = sorted({run["label"] for run in learners} - set(plan.curves))
    if others:
        problems.append(f"curves the plan did not fix: {', '.join(others)}")
    short = sorted(run["name"] for run in learners if run["total_steps"] != plan.total_steps)
    if short:
        problems.append(f"runs not at the plan's {plan.total_steps} env steps: {', '.join(short)}")
    return problems


def plan_entry(plan: Plan, record: dict) -> dict:
    """The record's ``plan`` entry: the plan itself and its rule in words, after checking the record against it
    (a ValueError lists what differs: a plan decides only on the runs it fixed, all of them finished)."""
    problems = unmet(plan, record)
    if problems:
        raise ValueError(f"the record is not plan {plan.name}'s as fixed: " + "; ".join(problems))
    fields = {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(plan).items()}
    return {**fields, "rule": plan.rule}  # as JSON holds it: the record in memory equals the one read back


def primary_of(record: dict) -> tuple[str, ...] | None:
    """The claims a record's plan made its primary family (``record["plan"]``), or None for a record without a
    plan (all its claims on the paper's metric are then the primary family)."""
    plan = record.get("plan")
    return tuple(plan["primary"]) if plan else None
