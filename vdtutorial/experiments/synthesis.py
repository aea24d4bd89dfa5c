"""What the shipped records say together, in sentences: the synthesis the README and chapter 10 print.

Each claim's table row says one thing about one figure. A reader leaves with a few sentences that join them: does
VD end above L2 in the paper's own setting, on which settings does its advantage hold in state mode, what the
seeds could not see. Every number and every verdict in those sentences is read here from the records
(``data/results/*/*.json``, as :func:`~vdtutorial.experiments.effects.claim_effects` and
:func:`~vdtutorial.experiments.results.rederive` wrote them), so the words change when the records do, and a test
compares the README's paragraph with this function's output.

Taught in chapter 10.
"""

from __future__ import annotations

from collections import defaultdict

from vdtutorial.experiments.effects import demo_seed_of
from vdtutorial.experiments.looks import RULE

#: The records the synthesis reads: the folder under data/results/ of each figure's full-scale record, and the
#: ablations' record (:mod:`vdtutorial.experiments.ablation_record`).
FOLDERS = ("fig4", "fig4_rgbd", "fig5", "fig6", "fig6_demos1", "fig7", "ablations")
#: The figure each record belongs to (records of one figure and observation are draws of its demonstrations).
FIGURE_OF = {
    "fig4": "Fig. 4 (state)",
    "fig4_rgbd": "Fig. 4 (images)",
    "fig5": "Fig. 5",
    "fig6": "Fig. 6",
    "fig6_demos1": "Fig. 6",
    "fig7": "Fig. 7",
}


def _primary(record: dict, text: str) -> dict:
    """A claim of ``record`` on its paper's metric, by its words."""
    return next(e for e in record["summary"]["claims"] if e["metric"] == record["metric"] and e["text"] == text)


def _effect(e: dict) -> str:
    return f"{e['estimate']:+.1f} ({e['low']:+.1f} to {e['high']:+.1f})"


def _setting(text: str, folder: str) -> str:
    """Where a state-mode "VD ends above L2" claim was tested, in words."""
    where = text.removeprefix("VD ends above L2").strip()
    where = "in grasping" if where.startswith("(grasping") else where or "at Fig. 4's setting"
    return where + (", second draw of the data" if folder == "fig6_demos1" else "")


def _state_vd_against_l2(records: dict[str, dict]) -> dict[str, list[str]]:
    """The state-mode "VD ends above L2" claims by Holm verdict (rows restating Fig. 4's runs left out): the setting
    and the effect of each."""
    by_verdict = defaultdict(list)
    for folder in ("fig4", "fig5", "fig6", "fig6_demos1", "fig7"):
        record = records[folder]
        for e in record["summary"]["claims"]:
            if (
                e["metric"] == record["metric"]
                and e["measure"] == "final"
                and e["a"].startswith("VD")
                and e["b"].startswith("L2")
                and e["text"].startswith("VD ends above L2")
                and not e.get("same_runs")
            ):
                by_verdict[e["holm_verdict"]].append(f"{_setting(e['text'], folder)} ({e['estimate']:+.1f})")
    return by_verdict


def _images(records: dict[str, dict]) -> str:
    record = records["fig4_rgbd"]
    final, reach = (
        _primary(record, "VD ends above L2"),
        next(
            e
            for e in record["summary"]["claims"]
            if e["metric"] == record["metric"] and e["measure"] == "steps_to_reach"
        ),
    )
    confirmed = [
        e for e in record["summary"]["claims"] if e["metric"] == record["metric"] and e["holm_verdict"] == "confirmed"
    ]
    crossing = [e for e in confirmed if e.get("across_batches")]
    ends = "ends above" if final["holm_verdict"] == "confirmed" else "does not end above"
    text = (
        f"**In the paper's own setting (images, Fig. 4)** VD {ends} L2: {_effect(final)} successes per 200 steps, "
        f"{final['holm_verdict']} after Holm with {final['n_a']} seeds each, so an advantage above "
        f"{final['high']:.1f} is ruled out and a smaller one is not. VD reaching L2's final level within 42% of "
        f"the budget is {reach['holm_verdict']}. Confirmed after Holm: "
        + ("; ".join(f"{e['text']} ({_effect(e)}, seeds {e['n_a']} / {e['n_b']})" for e in confirmed) or "nothing")
        + "."
    )
    for e in crossing:
        within = e.get("within_shared_batches")
        text += (
            f" '{e['text']}' compares seeds of different batches of runs"
            + (
                f"; within the batches both curves ran in it is {_effect(within)}, p = {within['p_value']:.2g} "
                f"({within['seeds'][0]} / {within['seeds'][1]} seeds)"
                if within
                else ""
            )
            + "."
        )
    return text


def _state(records: dict[str, dict]) -> str:
    by_verdict = _state_vd_against_l2(records)
    fig4 = records["fig4"]
    final = fig4["summary"]["final"]
    premise = _primary(fig4, "VD ends above no pre-training")
    return (
        f"**In state mode VD's advantage depends on the setting.** VD ends above L2 "
        f"{'; '.join(by_verdict['confirmed']) or 'nowhere'}; it ends below "
        f"{'; '.join(by_verdict['contradicted']) or 'nowhere'}; the seeds cannot tell them apart "
        f"{'; '.join(by_verdict['not confirmed']) or 'nowhere'} (Holm verdicts; effects in successes per 200 "
        f"steps, grasping in reward). On state reaching, where no pre-training ran (Fig. 4), it ends "
        f"{final['no pre-training']['mean'] - final['VD']['mean']:.1f} above VD and "
        f"{final['no pre-training']['mean'] - final['L2']['mean']:.1f} above L2 ('VD ends above no pre-training' "
        f"is {premise['holm_verdict']}): VD's reaching wins in state mode come from a setting where the paper's "
        f"premise, that pre-training helps RL, does not hold for the final level."
    )


def _limits(records: dict[str, dict]) -> str:
    reaching = [
        e["detectable"]
        for folder in ("fig4", "fig4_rgbd", "fig5", "fig6", "fig6_demos1")
        for e in records[folder]["summary"]["claims"]
        if e["metric"] == "successes" and e["measure"] == "final" and e["text"].startswith("VD ends above L2")
    ]
    grasp = _primary(records["fig7"], "VD ends above L2 (grasping)")["detectable"]
    draws = defaultdict(set)
    for folder in FIGURE_OF:
        draws[FIGURE_OF[folder]].add(demo_seed_of(records[folder]))
    several = {figure: sorted(seeds) for figure, seeds in draws.items() if len(seeds) > 1}
    fig5 = _primary(records["fig5"], "VD ends above L2 with 2000 demonstrations")
    looks = fig5.get("looks") if isinstance(fig5.get("looks"), dict) else None
    text = (
        f"**What the seeds can see.** Between VD and L2 on reaching, the smallest difference the seeds find "
        f"with 80% power at Holm's level is {min(reaching):.1f} to {max(reaching):.1f} successes per 200 steps "
        f"({grasp:.1f} in grasping reward); smaller differences are not excluded by a *not confirmed*. Each "
        f"figure rests on one draw of the demonstrations"
        + "".join(f", except {figure} (draws {', '.join(map(str, seeds))})" for figure, seeds in several.items())
        + "."
    )
    if looks:
        text += (
            f" Fig. 5 at 2000 demonstrations was looked at after {looks['stage_seeds'][0][0]} seeds and then "
            f"extended by {looks['stage_seeds'][1][0]}: its verdict uses a {RULE} (stages "
            f"{looks['stage_estimates'][0]:+.1f} and {looks['stage_estimates'][1]:+.1f}, combined one-sided "
            f"p = {looks['combined_p_one_sided']:.2g}, the claim's p = {fig5['p_value']:.2g}: "
            f"{fig5['holm_verdict']} after Holm)."
        )
    return text


def _ablations(records: dict[str, dict]) -> str:
    """Where VD's state-mode wins come from: the ablations' eight claims, setting by setting, with the plan's
    reading of each setting (``docs/plan-ablations-and-image-fig5.md``, section 2)."""
    record = records["ablations"]
    rates = {s["setting"]: s["dropout_rate"] for s in record["sources"]}
    seeds = sorted({len(s) for s in record["seeds"].values()})
    settings = []
    for figure, reading in record["reading"].items():
        where, _, verdict = reading.partition(": ")
        claims = [c for c in record["claims"] if c["figure"] == figure]
        named = "; ".join(
            f"{c['a'].split(',')[0]} minus {c['b'].split(',')[0]} {_effect(c)}, {c['holm_verdict']}" for c in claims
        )
        settings.append(
            f"{where.replace(figure, 'Fig. ' + figure.removeprefix('fig'))} (binary dropout at rate "
            f"{rates[figure]:g}): {named}; the plan's reading: {verdict}."
        )
    unpruned = [c for c in record["claims"] if c["a"].startswith("VD without pruning") and c["b"].startswith("L2")]
    text = (
        f"**Where VD's wins in state mode come from.** Two ablations ran beside VD and L2 where VD wins, "
        f"{' or '.join(map(str, seeds))} seeds per method, their eight claims one Holm family, the test and the "
        f"reading fixed before the runs: VD without pruning (the same clone, every weight kept) and binary dropout at "
        f"VD's mean dropout rate (effects in successes per 200 steps, Holm verdicts). " + " ".join(settings)
    )
    if unpruned and all(c["holm_verdict"] == "confirmed" for c in unpruned):
        text += " The pruning is not what wins: with every weight kept, VD still ends above L2 in both settings."
    if len(set(r.partition(": ")[2] for r in record["reading"].values())) > 1:
        text += " The two settings' readings differ, so what else makes the win depends on the setting."
    return text


def _meaning(records: dict[str, dict]) -> str:
    images = records["fig4_rgbd"]
    final = _primary(images, "VD ends above L2")
    reach_holds = any(
        e["measure"] == "steps_to_reach" and e["holm_verdict"] == "confirmed"
        for e in images["summary"]["claims"]
        if e["metric"] == images["metric"]
    )
    headline = final["holm_verdict"] == "confirmed" or reach_holds
    by_verdict = _state_vd_against_l2(records)
    mixed = bool(by_verdict["confirmed"]) and bool(by_verdict["contradicted"])
    return (
        "**What this means for the paper.** "
        + (
            "Its headline, that VD pre-training lets TRPO reach L2's level sooner and end higher, "
            + ("holds in part on images" if headline else "does not reproduce in its own setting")
            + "; pre-training of either kind beating learning from scratch on images does. "
        )
        + (
            "In state mode VD's effect changes sign with the data set and its noise, so it is not a property of "
            "the method alone in our setting, "
            if mixed
            else ""
        )
        + "and the settings where VD wins in state mode are the open question on images."
    )


def synthesis(records: dict[str, dict]) -> str:
    """The shipped records' findings as Markdown paragraphs (``records``: ``{folder: record}`` for
    :data:`FOLDERS`): images, state mode by setting, where VD's state-mode wins come from (the ablations), what the
    seeds and draws can see (and Fig. 5's two looks), and what it means for the paper."""
    return "\n\n".join((_images(records), _state(records), _ablations(records), _limits(records), _meaning(records)))
