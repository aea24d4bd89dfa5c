"""Batches of seeds: the separate commands whose runs a merged record holds, and the comparisons that cross them.

A record merged with ``rederive --add`` holds runs of several commands (``merged``): a first batch of seeds, then
more, perhaps on another CPU's kernels, from another checkout, with checkpoints pre-trained in another folder. A
run is a pure function of its settings and seed, so seeds from two batches are meant to be replicates of one
experiment; that is an assumption, and this module is where it is checked:

* a batch is the runs of one command, or of several that recorded the same CPU kernels and, where recorded, the
  same CPU model (:func:`batches_of`);
* a claim whose two curves draw their seeds from different sets of batches (one curve run only in the first, say)
  **crosses batches**: any difference between the batches is then part of its effect. The record marks it
  (``across_batches``) and the tables say so;
* for each curve run in two batches, the difference between them (final level and area under the curve, Welch)
  says whether the batches behaved as replicates (:func:`batch_differences`), beside what the record says differed
  between them (:func:`batch_settings`).

Taught in appendix A5.
"""

from __future__ import annotations

from vdtutorial.experiments.effects import (
    holm_rejections,
    of_seeds,
    per_run,
    run_summaries,
    welch_interval,
    welch_p_value,
)


def _kernels_key(kernels):
    """What identifies a command's CPU kernels: the recorded settings that are set (None: not recorded)."""
    if not isinstance(kernels, dict):
        return None
    return tuple(sorted((key, value) for key, value in kernels.items() if value))


def _part_runs(parts: list[dict], record: dict) -> list[set[tuple[str, int]]]:
    """Each part's runs as (curve, seed) pairs. A part that names its curves (``labels``, which merges write since
    parts could add seeds to some curves only) holds those curves' runs at its seeds; one that does not (merged
    before then) holds every curve's runs at its seeds that no part naming its curves holds."""
    runs = {(run["label"], run["seed"]) for run in record["runs"]}
    named = {(label, seed) for part in parts if "labels" in part for label in part["labels"] for seed in part["seeds"]}
    return [
        {
            (label, seed)
            for label, seed in runs
            if seed in part["seeds"] and (label in part["labels"] if "labels" in part else (label, seed) not in named)
        }
        for part in parts
    ]


def batches_of(record: dict) -> list[dict]:
    """The batches of a record's runs, in order: the runs of one command, or of several commands that recorded the
    same CPU kernels (the records hold no code commit, so commands on the same kernels count as one batch; a
    command whose kernels were not recorded is a batch of its own). The CPU model is part of the kernels where a
    record has it (records made before it was kept do not): a command that names its CPU and one that does not
    are two batches, since nothing says they ran on the same machine. Each with its ``seeds``, its ``runs`` ((curve,
    seed) pairs: two commands may run the same seed of different curves), ``kernels``, ``commands`` and
    ``state_dirs`` (one batch, the record itself, when nothing was merged into it)."""
    parts = [entry for entry in record.get("merged") or [] if "seeds" in entry] or [
        {"seeds": record["seeds"], **{key: record.get(key) for key in ("kernels", "command", "state_dir")}}
    ]
    batches: list[dict] = []
    for part, runs in zip(parts, _part_runs(parts, record)):
        key = _kernels_key(part.get("kernels"))
        same = next((b for b in batches if key is not None and _kernels_key(b["kernels"]) == key), None)
        if same is None:
            batches.append(
                {
                    "seeds": sorted(set(part["seeds"])),
                    "runs": runs,
                    "kernels": part.get("kernels"),
                    "commands": [part["command"]],
                    "state_dirs": [part.get("state_dir")],
                }
            )
        else:
            same["seeds"] = sorted(set(same["seeds"]) | set(part["seeds"]))
            same["runs"] |= runs
            same["commands"].append(part["command"])
            same["state_dirs"].append(part.get("state_dir"))
    return batches


def batch_indices(batches: list[dict], label: str, seeds) -> list[int]:
    """The batches (indices into ``batches``, a record's :func:`batches_of`) that curve ``label``'s ``seeds`` come
    from."""
    return sorted({k for k, batch in enumerate(batches) for seed in seeds if (label, seed) in batch["runs"]})


def _claim_seeds(record: dict, label: str, effect: dict) -> list[int]:
    """The seeds of curve ``label`` a claim used: the first look's when it was judged there, else all the curve's."""
    if isinstance(effect.get("looks"), str):
        return record["looks"][0]["seeds"][label]
    return sorted({run["seed"] for run in record["runs"] if run["label"] == label})


def mark_batches(effects: list[dict], record: dict, rows: list[dict] | None = None) -> list[dict]:
    """``effects`` with, on each claim between two learning curves, the batches each curve's seeds came from
    (``batches``) and whether they differ (``across_batches``); claims against the expert's episodes, and every
    claim of a record made by one command, as they are. With the record's ``rows``, a difference of means that
    crosses batches also gets the same comparison on the seeds of the batches both curves ran in
    (``within_shared_batches``: estimate, 95% interval, two-sided p and seeds)."""
    batches = batches_of(record)
    if len(batches) == 1:
        return effects
    marked, groups = [], {}
    for effect in effects:
        if effect.get("n_b_counts") == "episodes" or "a" not in effect:
            marked.append(effect)
            continue
        used = [batch_indices(batches, effect[key], _claim_seeds(record, effect[key], effect)) for key in ("a", "b")]
        extra = {"batches": used, "across_batches": used[0] != used[1]}
        shared = sorted(set(used[0]) & set(used[1]))
        if extra["across_batches"] and shared and rows is not None and effect["measure"] != "steps_to_reach":
            if effect["metric"] not in groups:
                groups[effect["metric"]] = per_run(rows, effect["metric"])
            shared_runs = set().union(*(batches[k]["runs"] for k in shared))
            values = [
                run_summaries(
                    of_seeds(
                        groups[effect["metric"]][effect[key]],
                        [s for s in groups[effect["metric"]][effect[key]]["seeds"] if (effect[key], s) in shared_runs],
                    ),
                    effect["measure"],
                    int(record["window"]),
                )
                for key in ("a", "b")
            ]
            estimate, low, high = welch_interval(*values)
            extra["within_shared_batches"] = {
                "estimate": estimate,
                "low": low,
                "high": high,
                "p_value": welch_p_value(*values),
                "seeds": [len(v) for v in values],
            }
        marked.append({**effect, **extra})
    return marked


def batch_settings(record: dict) -> str:
    """What each batch of a record ran with, as Markdown: seeds, CPU kernels, the commands (their ``--out``, where
    checkpoints are pre-trained when the shipped ones do not match), and the state folders."""
    lines = ["| batch | seeds | kernels | commands | states |", "|---|---|---|---|---|"]
    for k, batch in enumerate(batches_of(record), 1):
        kernels = batch["kernels"]
        if isinstance(kernels, dict):  # torch's capability, then every variable that was set (a pin), then the CPU
            named = ("torch_cpu_capability", "cpu")
            pins = [f"{name}={value}" for name, value in kernels.items() if value and name not in named]
            cpu = f" (on {kernels['cpu']})" if kernels.get("cpu") else ""
            kernels = ", ".join([kernels.get("torch_cpu_capability", "?"), *pins]) + cpu
        else:
            kernels = str(kernels)
        seeds = batch["seeds"]
        consecutive = len(seeds) > 1 and seeds == list(range(seeds[0], seeds[-1] + 1))
        span = f"{seeds[0]}-{seeds[-1]}" if consecutive else ", ".join(map(str, seeds))
        commands = "; ".join(f"`{command}`" for command in batch["commands"])
        lines.append(f"| {k} | {span} | {kernels} | {commands} | {'; '.join(f'`{d}`' for d in batch['state_dirs'])} |")
    return "\n".join(lines)


def batch_differences(record: dict, rows: list[dict], measures: tuple[str, ...] = ("final", "auc")) -> list[dict]:
    """For every curve with seeds in two or more batches, each later batch against the first on the paper's metric:
    the difference of means (later minus first) with Welch's 95% interval and two-sided p, per measure."""
    groups = per_run(rows, record["metric"])
    batches = batches_of(record)
    out = []
    for label, group in groups.items():
        if group["values"].ndim == 1:
            continue
        by_batch = [[i for i, seed in enumerate(group["seeds"]) if (label, seed) in batch["runs"]] for batch in batches]
        present = [k for k, index in enumerate(by_batch) if index]
        for later in present[1:]:
            for measure in measures:
                values = run_summaries(group, measure, int(record["window"]))
                first, other = values[by_batch[present[0]]], values[by_batch[later]]
                estimate, low, high = welch_interval(other, first)
                out.append(
                    {
                        "label": label,
                        "measure": measure,
                        "batches": [present[0] + 1, later + 1],
                        "seeds": [len(first), len(other)],
                        "mean_first": float(first.mean()),
                        "mean_later": float(other.mean()),
                        "estimate": estimate,
                        "low": low,
                        "high": high,
                        "p_value": welch_p_value(other, first),
                    }
                )
    return out


def batch_difference_table(differences: list[dict]) -> str:
    """:func:`batch_differences` as Markdown, one row per curve, measure and later batch."""
    lines = [
        "| curve | measure | batches | seeds | first batch | later batch | later - first (95% interval) | p |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for d in differences:
        lines.append(
            f"| {d['label']} | {d['measure']} | {d['batches'][0]} / {d['batches'][1]} | "
            f"{d['seeds'][0]} / {d['seeds'][1]} | {d['mean_first']:.3g} | {d['mean_later']:.3g} | "
            f"{d['estimate']:+.3g} ({d['low']:+.3g} to {d['high']:+.3g}) | {d['p_value']:.2g} |"
        )
    return "\n".join(lines)


def batches_report(records: dict[str, tuple[dict, list[dict]]]) -> str:
    """The results page's "Batches of seeds" tables: for each record of two or more batches (``records``:
    ``{heading: (record, rows)}``), what each batch ran with and each curve's difference between its batches, and
    the claims that cross batches with their comparison within the shared batches."""
    count, smallest, rejected = smallest_batch_p(records)
    verdict = "rejects" if rejected else "does not reject"
    blocks = [
        (
            f"Over the {count} distinct between-batch differences below, the smallest two-sided p is "
            f"{smallest:.2g}; Holm's procedure over all of them {verdict} it at 5%."
        )
    ]
    for heading, (record, rows) in records.items():
        if len(batches_of(record)) < 2:
            continue
        differences = batch_difference_table(batch_differences(record, rows))
        block = [f"**{heading}**", "", batch_settings(record), "", differences]
        crossing = [
            e for e in record["summary"]["claims"] if e.get("across_batches") and e["metric"] == record["metric"]
        ]
        for e in crossing:
            within = e.get("within_shared_batches")
            block += [
                "",
                f"Across batches: {e['text']} ({e['measure']}), seeds from batches "
                f"{', '.join(str(k + 1) for k in e['batches'][0])} against "
                f"{', '.join(str(k + 1) for k in e['batches'][1])}: {e['estimate']:+.3g} "
                f"({e['low']:+.3g} to {e['high']:+.3g}), Holm {e['holm_verdict']}"
                + (
                    f"; within the shared batches {within['estimate']:+.3g} ({within['low']:+.3g} to "
                    f"{within['high']:+.3g}), p = {within['p_value']:.2g}, seeds {within['seeds'][0]} / "
                    f"{within['seeds'][1]}"
                    if within
                    else ""
                )
                + ".",
            ]
        blocks.append("\n".join(block))
    return "\n\n".join(blocks)


def smallest_batch_p(records: dict[str, tuple[dict, list[dict]]]) -> tuple[int, float, bool]:
    """Over every between-batch difference of ``records`` (distinct curves only: a curve shared by two records, as
    Fig. 4's runs are by Figs. 5 and 6, counts once): how many there are, the smallest p-value, and whether Holm's
    procedure over all of them rejects it (True: the batches differ beyond chance somewhere)."""
    seen, p_values = set(), []
    for record, rows in records.values():
        for d in batch_differences(record, rows):
            key = (round(d["mean_first"], 9), round(d["mean_later"], 9), d["measure"])
            if key not in seen:
                seen.add(key)
                p_values.append(d["p_value"])
    smallest = min(range(len(p_values)), key=p_values.__getitem__)
    return len(p_values), p_values[smallest], holm_rejections(p_values)[smallest]
