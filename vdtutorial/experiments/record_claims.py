"""A record's claims recomputed from its rows and stored in it: the step that ``claims`` and ``rederive`` share.

The claims themselves are :mod:`~vdtutorial.experiments.effects`'s (effect sizes, Welch intervals, Holm), judged by
the sequential rule of :mod:`~vdtutorial.experiments.looks` where seeds were added after a look, tested as a
pre-registered plan fixed (:mod:`~vdtutorial.experiments.plans`) where the record names one, and marked by
:mod:`~vdtutorial.experiments.batches` where their two curves come from different batches of seeds. This module
only puts them together for one folder, so that none of them needs to import another from above.

Not taught in a chapter: the step behind ``python -m vdtutorial claims`` and ``rederive`` (docs/results.md).
"""

from __future__ import annotations

import json
from pathlib import Path

from vdtutorial.experiments.batches import mark_batches
from vdtutorial.experiments.curves import record_window
from vdtutorial.experiments.effects import claim_effects, claim_table
from vdtutorial.experiments.looks import looks_of
from vdtutorial.experiments.plans import plan_entry, plan_named, primary_of
from vdtutorial.runner.rows import read_rows, results_file


def write_claims(folder: str | Path) -> str:
    """Recompute the claims of the experiment in ``folder`` (``NAME.csv.gz`` and ``NAME.json``) from its rows,
    store them in the JSON record's summary, and return them as a Markdown table: docs/results.md quotes
    these tables (``python -m vdtutorial claims FOLDER`` prints them)."""
    folder = Path(folder)
    record_path = next(folder.glob("*.json"))
    record = json.loads(record_path.read_text())
    rows = read_rows(results_file(folder, record["experiment"]))
    if record.get("plan"):  # a plan decides only on all of its runs (ValueError otherwise, nothing written)
        plan_entry(plan_named(record["plan"]["name"]), record)
    claims = claim_effects(
        record["experiment"],
        rows,
        record["metric"],
        record_window(record),
        looks=looks_of(record),
        primary=primary_of(record),
    )
    effects = mark_batches(claims, record, rows)
    record.setdefault("summary", {})["claims"] = effects
    record_path.write_text(json.dumps(record, indent=1, default=str))
    return claim_table(effects)
