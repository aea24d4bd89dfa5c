"""Where VD's state-mode wins come from: the two ablations' claims, as the plan fixed them before the runs.

Where VD ends above L2 in state mode (Fig. 6 at Sigma = 0.25, first draw of the demonstrations; Fig. 5 at 2000
demonstrations), two methods of the table take one ingredient of VD away at a time
(:mod:`vdtutorial.methods`): VD without pruning keeps every weight of VD's own network, and binary dropout keeps
multiplicative noise while cloning but drops the learned per-weight variances, at the rate matched to VD's
(:func:`vdtutorial.analysis.dropout_rate.matched_dropout_rate`). Each setting asks four questions of the final
level: does each ablation end at VD's level, and does each end above L2. The plan
(``docs/plan-ablations-and-image-fig5.md``, section 2) makes the eight claims of both settings one family, tested
with Holm's correction at a family-wise 5%, and fixes how the verdicts are read:

- the pruning is what wins if "VD without pruning ends at VD's level" is contradicted (it ends below VD) and "VD
  without pruning ends above L2" is not confirmed;
- the multiplicative noise alone wins if "binary dropout ends above L2" is confirmed;
- the learned variances matter if "binary dropout ends at VD's level" is contradicted while the first is not.

A claim "X ends at VD's level" is the comparison X - VD with the direction of "X ends above VD": contradicted means
X ends below VD, confirmed means above; "not confirmed" or "negligible" is what "at VD's level" predicts.

Each setting's runs are one command (one batch: VD and L2 are run again beside the ablations), so every comparison
is within a batch. :func:`ablation_effects` reads the two settings' rows together, so that the eight claims are
one Holm family on the paper's metric, as in every other record (:func:`~vdtutorial.experiments.effects.claim_effects`).

:func:`plan_reading` turns the verdicts into the plan's sentences; the record of the finished runs is
:mod:`~vdtutorial.experiments.ablation_record`.

Not taught in a chapter: the runs it judges are under way (the plan and its commands are in docs/).
"""

from __future__ import annotations

from dataclasses import dataclass

from vdtutorial.experiments.effects import Claim, claim_effects
from vdtutorial.methods import METHOD_LABELS


@dataclass(frozen=True)
class AblationSetting:
    """One of the two settings: the experiment (``figure``), its one data set as the curve labels name it
    (``curve_suffix``), and the binary dropout rate matched to VD's checkpoints of that setting, measured before the
    runs (the plan's table of rates)."""

    figure: str
    curve_suffix: str
    dropout_rate: float

    def label(self, method: str) -> str:
        """The label of ``method``'s curves in this setting, as the experiment writes it."""
        return f"{METHOD_LABELS[method]}, {self.curve_suffix}"

    @property
    def dropout(self) -> str:
        """Binary dropout's name at this setting's matched rate (the rate is part of the method's name)."""
        return f"dropout@{self.dropout_rate:g}"


#: The worktree commit every run of both settings is made from (the plan's "Worktree commit the runs are made from").
RUNS_COMMIT = "4ab9285"
#: The plan's seeds per method and setting, and each run's budget in env steps (the stopping rule: all runs to it).
PLAN_SEEDS = tuple(range(10))
PLAN_STEPS = 300_000

#: The plan's two settings, each with the rate the plan fixed for it: Fig. 6 at Sigma = 0.25, Fig. 5 at 2000 demos.
SETTINGS = (
    AblationSetting("fig6", "Sigma=0.25", 0.32),
    AblationSetting("fig5", "2000 demos", 0.16),
)


def ablation_claims(settings: tuple[AblationSetting, ...] = SETTINGS) -> tuple[Claim, ...]:
    """The plan's four claims per setting, on the final level (the paper's metric)."""
    claims = []
    for s in settings:
        vd, l2, unpruned, dropout = (s.label(m) for m in ("vd", "l2", "vd_unpruned", s.dropout))
        where = s.curve_suffix.replace("=", " = ")
        claims += [
            Claim(s.figure, f"VD without pruning ends at VD's level ({where})", "final", unpruned, vd),
            Claim(s.figure, f"binary dropout ends at VD's level ({where})", "final", dropout, vd),
            Claim(s.figure, f"VD without pruning ends above L2 ({where})", "final", unpruned, l2),
            Claim(s.figure, f"binary dropout ends above L2 ({where})", "final", dropout, l2),
        ]
    return tuple(claims)


def ablation_effects(rows: list[dict], metric: str, window: int | None = None) -> list[dict]:
    """The eight claims judged on ``rows``, the two settings' rows together (their labels differ by setting), so
    that the claims on the paper's metric are one Holm family. Claims whose curves are missing are left out."""
    return claim_effects("ablations", rows, metric, window=window, claims=ablation_claims())


#: The plan's fixed readings of one setting's four verdicts, in the plan's order
#: (module docstring, "fixes how the verdicts are read").
PRUNING_WINS = "the pruning is what wins"
NOISE_WINS = "the multiplicative noise alone wins"
VARIANCES_MATTER = "the learned variances matter"
OTHER_PATTERN = "another pattern than the plan's three, reported as it is with its intervals"


def _where(setting: AblationSetting) -> str:
    """The setting as the claims' texts name it ("Sigma = 0.25", "2000 demos")."""
    return setting.curve_suffix.replace("=", " = ")


def setting_readings(verdicts: tuple[str, str, str, str]) -> list[str]:
    """Which of the plan's readings one setting's four Holm verdicts give, in the claims' order: (1) VD without
    pruning ends at VD's level, (2) binary dropout ends at VD's level, (3) VD without pruning ends above L2, (4)
    binary dropout ends above L2. More than one may hold; none is :data:`OTHER_PATTERN`'s case."""
    unpruned_vd, dropout_vd, unpruned_l2, dropout_l2 = verdicts
    readings = []
    if unpruned_vd == "contradicted" and unpruned_l2 != "confirmed":
        readings.append(PRUNING_WINS)
    if dropout_l2 == "confirmed":
        readings.append(NOISE_WINS)
    if dropout_vd == "contradicted" and unpruned_vd != "contradicted":
        readings.append(VARIANCES_MATTER)
    return readings


def plan_reading(effects: list[dict], settings: tuple[AblationSetting, ...] = SETTINGS) -> dict[str, str]:
    """The plan's sentence for each setting (keyed by its experiment, "fig6" and "fig5"), read from the Holm
    verdicts of :func:`ablation_effects`'s primary family (the verdicts the family-wise 5% allows). Where several
    readings hold they are all given; where none does, the four claims are given as they are: effect, 95% interval
    and Holm verdict."""
    primary = {e["text"]: e for e in effects if e["family"] == "primary"}
    claims = ablation_claims(settings)
    sentences = {}
    for k, setting in enumerate(settings):
        own = [primary[c.text] for c in claims[4 * k : 4 * k + 4]]
        readings = setting_readings(tuple(e["holm_verdict"] for e in own))
        head = f"{setting.figure}, {_where(setting)}: "
        if readings:
            sentences[setting.figure] = head + "; and ".join(readings)
            continue
        given = "; ".join(
            f"{e['text']}: {e['estimate']:+.3g} ({e['low']:+.3g} to {e['high']:+.3g}), {e['holm_verdict']}" for e in own
        )
        sentences[setting.figure] = f"{head}{OTHER_PATTERN}: {given}"
    return sentences
