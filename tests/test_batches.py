"""Batches of seeds: claims whose curves come from different commands are marked, and the batches compared."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from vdtutorial.experiments import read_rows, results_file
from vdtutorial.experiments.batches import (
    batch_differences,
    batches_report,
    mark_batches,
)
from vdtutorial.experiments.effects import claim_effects, claim_table
from vdtutorial.experiments.looks import looks_table
from vdtutorial.settings import data_dir

from flat_curves import flat_rows

ROOT = Path(__file__).resolve().parents[1]
#: The records the results page's "Batches of seeds" tables are generated from.
BATCH_RECORDS = {
    "Fig. 4, state": "fig4",
    "Fig. 4, images": "fig4_rgbd",
    "Fig. 5, state": "fig5",
    "Fig. 6, state": "fig6",
    "Fig. 7, state": "fig7",
}


def _load(folder: str) -> tuple[dict, list[dict]]:
    path = data_dir() / "results" / folder
    record = json.loads(next(path.glob("*.json")).read_text())
    return record, read_rows(results_file(path, record["experiment"]))


def test_a_claim_whose_curves_ran_in_different_batches_is_marked_with_its_within_batch_comparison():
    """VD ran in both batches (seeds 0-2, then 3-9), no pre-training only in the first: the claim crosses batches,
    and its comparison on seeds 0-2 alone is Welch's on those seeds. VD against L2 (both in both batches) does not."""
    rng = np.random.default_rng(2)
    vd, l2 = ({s: level + rng.normal() for s in range(10)} for level in (60, 58))
    scratch = {s: 5 + rng.normal() for s in range(3)}
    rows = flat_rows("VD", "vd", vd) + flat_rows("L2", "l2", l2) + flat_rows("no pre-training", "none", scratch)
    record = {
        "seeds": list(range(10)),
        "window": 5,
        "metric": "successes",
        "runs": [
            {"label": label, "seed": s}
            for label, seeds in (("VD", vd), ("L2", l2), ("no pre-training", scratch))
            for s in seeds
        ],
        "merged": [
            {"seeds": [0, 1, 2], "kernels": "a", "command": "first", "state_dir": "x"},
            {"command": "merge"},
            {"seeds": list(range(3, 10)), "kernels": "b", "command": "second", "state_dir": "y"},
        ],
    }
    effects = {
        e["text"]: e
        for e in mark_batches(claim_effects("fig4", rows, "successes", window=5), record, rows)
        if e["metric"] == "successes"
    }
    crossing = effects["VD ends above no pre-training"]
    assert crossing["across_batches"] and crossing["batches"] == [[0, 1], [0]]
    within = stats.ttest_ind([vd[s] for s in range(3)], list(scratch.values()), equal_var=False)
    assert crossing["within_shared_batches"]["p_value"] == pytest.approx(within.pvalue, rel=1e-9)
    assert crossing["within_shared_batches"]["seeds"] == [3, 3]
    assert not effects["VD ends above L2"]["across_batches"]
    assert "(across batches of seeds)" in claim_table([crossing]) and "across" not in claim_table(
        [effects["VD ends above L2"]]
    )
    later = next(d for d in batch_differences(record, rows) if d["label"] == "L2" and d["measure"] == "final")
    first, second = [l2[s] for s in range(3)], [l2[s] for s in range(3, 10)]
    assert later["estimate"] == pytest.approx(np.mean(second) - np.mean(first))
    assert later["p_value"] == pytest.approx(stats.ttest_ind(second, first, equal_var=False).pvalue, rel=1e-9)


def test_the_image_fig4_above_no_pretraining_is_flagged_until_no_pretraining_has_seeds_3_to_9():
    """No pre-training ran seeds 0-2 only; within them VD's final level is +71.3 (+19.1 to +123.5), p = 0.028."""
    record, _ = _load("fig4_rgbd")
    claim = next(
        e
        for e in record["summary"]["claims"]
        if e["text"] == "VD ends above no pre-training" and e["metric"] == "successes"
    )
    scratch_seeds = sorted({r["seed"] for r in record["runs"] if r["label"] == "no pre-training"})
    assert claim["across_batches"] == (scratch_seeds != record["seeds"])
    if claim["across_batches"]:
        within = claim["within_shared_batches"]
        assert (within["estimate"], within["low"], within["high"]) == pytest.approx((71.3, 19.1, 123.5), abs=0.05)
        assert within["p_value"] == pytest.approx(0.028, abs=5e-4)


def test_the_state_fig4_batches_differ_as_measured():
    """No pre-training's AUC: seeds 5-9 below seeds 0-4 by 9.8 (4.3 to 15.3), p = 0.0034; L2's final 80.4 against
    67.0, p = 0.053."""
    record, rows = _load("fig4")
    diffs = {(d["label"], d["measure"]): d for d in batch_differences(record, rows)}
    auc = diffs[("no pre-training", "auc")]
    assert (auc["estimate"], auc["low"], auc["high"]) == pytest.approx((-9.8, -15.3, -4.3), abs=0.05)
    assert auc["p_value"] == pytest.approx(0.0034, abs=5e-5)
    final = diffs[("L2", "final")]
    assert (final["mean_first"], final["mean_later"]) == pytest.approx((80.4, 67.0), abs=0.05)


def test_the_results_page_carries_the_generated_batch_and_look_tables():
    page = (ROOT / "docs" / "results.md").read_text()
    assert batches_report({heading: _load(folder) for heading, folder in BATCH_RECORDS.items()}) in page
    assert looks_table(_load("fig5")[0]["summary"]["claims"]) in page


def test_commands_on_the_same_kernels_are_one_batch():
    """No pre-training's seeds 3-9 run later by their own command, on the kernels of VD's seeds 3-9: the claim no
    longer crosses batches. A command whose kernels were not recorded stays a batch of its own."""
    avx512 = {"torch_cpu_capability": "AVX512", "ATEN_CPU_CAPABILITY": ""}
    record = {
        "seeds": list(range(10)),
        "runs": [{"label": label, "seed": s} for label in ("VD", "no pre-training") for s in range(10)],
        "merged": [
            {"seeds": [0, 1, 2], "kernels": {"torch_cpu_capability": "AVX2"}, "command": "a"},
            {"seeds": list(range(3, 10)), "kernels": avx512, "command": "b"},
            {"command": "merge"},
            {"seeds": [10], "kernels": "not recorded", "command": "c"},
            {"seeds": [11], "kernels": {"torch_cpu_capability": "AVX512"}, "command": "d"},
        ],
    }
    from vdtutorial.experiments.batches import batches_of

    batches = batches_of(record)
    assert [b["seeds"] for b in batches] == [[0, 1, 2], [3, 4, 5, 6, 7, 8, 9, 11], [10]]
    assert batches[1]["commands"] == ["b", "d"]
    effect = {"a": "VD", "b": "no pre-training", "measure": "final", "metric": "successes"}
    assert not mark_batches([effect], record)[0]["across_batches"]


def test_the_cpu_model_is_part_of_a_batch_where_it_was_recorded():
    """The same recorded kernels on two CPU models are two batches, and so are a command that names its CPU and one
    that does not (nothing says they ran on one machine); the batch table names the CPU after the kernels."""
    from vdtutorial.experiments.batches import batch_settings, batches_of

    avx512 = {"torch_cpu_capability": "AVX512", "OPENBLAS_CORETYPE": "Haswell"}
    record = {
        "seeds": list(range(4)),
        "runs": [{"label": "VD", "seed": s} for s in range(4)],
        "merged": [
            {"seeds": [0], "kernels": {**avx512, "cpu": "AMD EPYC"}, "command": "a"},
            {"seeds": [1], "kernels": {**avx512, "cpu": "Intel(R) Xeon(R)"}, "command": "b"},
            {"seeds": [2], "kernels": avx512, "command": "c"},
            {"seeds": [3], "kernels": {**avx512, "cpu": "AMD EPYC"}, "command": "d"},
        ],
    }
    assert [b["seeds"] for b in batches_of(record)] == [[0, 3], [1], [2]]
    table = batch_settings(record)
    assert "| 1 | 0, 3 | AVX512, OPENBLAS_CORETYPE=Haswell (on AMD EPYC) | `a`; `d` |" in table
    assert "| 3 | 2 | AVX512, OPENBLAS_CORETYPE=Haswell | `c` |" in table


def test_a_later_command_adding_one_curves_seeds_belongs_to_its_own_batch_for_that_curve_only():
    """The image Fig. 4's no pre-training at seeds 3-9 came after VD's seeds 3-9, by its own command: the two parts
    share seeds but not runs. Each curve's seeds belong to the part that ran them (``labels``; a part merged before
    parts named their curves holds the rest), so the claim is within batches when the kernels match and across them
    when they do not, with the shared batch's comparison on that batch's runs of each curve."""
    rng = np.random.default_rng(3)
    vd = {s: 60 + rng.normal() for s in range(10)}
    scratch = {s: 5 + rng.normal() for s in range(10)}
    rows = flat_rows("VD", "vd", vd) + flat_rows("no pre-training", "none", scratch)

    def record(later_kernels):
        return {
            "seeds": list(range(10)),
            "window": 5,
            "metric": "successes",
            "runs": [{"label": label, "seed": s} for label in ("VD", "no pre-training") for s in range(10)],
            "merged": [
                {"seeds": [0, 1, 2], "kernels": {"torch_cpu_capability": "AVX2"}, "command": "first"},
                {"seeds": list(range(3, 10)), "kernels": {"torch_cpu_capability": "AVX512"}, "command": "vd"},
                {"command": "merge"},
                {
                    "seeds": list(range(3, 10)),
                    "labels": ["no pre-training"],
                    "kernels": later_kernels,
                    "command": "none",
                },
                {"command": "merge"},
            ],
        }

    from vdtutorial.experiments.batches import batches_of

    effect = {"a": "VD", "b": "no pre-training", "measure": "final", "metric": "successes"}
    same = record({"torch_cpu_capability": "AVX512"})
    assert [b["seeds"] for b in batches_of(same)] == [[0, 1, 2], list(range(3, 10))]
    assert batches_of(same)[1]["commands"] == ["vd", "none"]
    assert mark_batches([effect], same, rows)[0] == {**effect, "batches": [[0, 1], [0, 1]], "across_batches": False}

    other = record({"torch_cpu_capability": "AVX512", "OPENBLAS_CORETYPE": "Haswell"})
    batches = batches_of(other)
    assert [sorted({label for label, _ in b["runs"]}) for b in batches] == [
        ["VD", "no pre-training"],
        ["VD"],
        ["no pre-training"],
    ]
    marked = mark_batches([effect], other, rows)[0]
    assert marked["batches"] == [[0, 1], [0, 2]] and marked["across_batches"]
    first = [vd[s] for s in range(3)], [scratch[s] for s in range(3)]
    assert marked["within_shared_batches"]["seeds"] == [3, 3]
    assert marked["within_shared_batches"]["estimate"] == pytest.approx(np.mean(first[0]) - np.mean(first[1]))
    differences = {(d["label"], d["measure"]): d for d in batch_differences(other, rows)}
    assert differences[("no pre-training", "final")]["batches"] == [1, 3]
    assert differences[("VD", "final")]["seeds"] == [3, 7]
