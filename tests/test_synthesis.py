"""The synthesis in words: every number in the README's and chapter 10's sentences comes from a shipped record."""

import copy
import json
import re
from pathlib import Path

import pytest

from vdtutorial.experiments.synthesis import FOLDERS, synthesis
from vdtutorial.settings import data_dir

ROOT = Path(__file__).resolve().parents[1]


def _records() -> dict:
    return {
        folder: json.loads(next((data_dir() / "results" / folder).glob("*.json")).read_text()) for folder in FOLDERS
    }


def _claim(record: dict, text: str) -> dict:
    return next(e for e in record["summary"]["claims"] if e["metric"] == record["metric"] and e["text"] == text)


def test_the_readme_carries_the_synthesis_of_the_shipped_records():
    """The README's paragraphs are the function's output on the shipped records, word for word: a sentence whose
    number differs from its record fails here."""
    readme = (ROOT / "README.md").read_text()
    for paragraph in synthesis(_records()).split("\n\n"):
        assert paragraph in readme


def test_chapter_10_prints_the_synthesis_from_the_records():
    cells = json.loads((ROOT / "notebooks" / "10_what_reproduced.ipynb").read_text())["cells"]
    code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    markdown = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    assert "synthesis(" in code
    assert not re.search(r"[+-]\d+\.\d \(", markdown), "an effect typed into the chapter's words"


def test_each_number_follows_its_record():
    """Change a record's numbers and verdicts, and the sentences change with them."""
    records = _records()
    text = synthesis(records)
    images = _claim(records["fig4_rgbd"], "VD ends above L2")
    assert f"{images['estimate']:+.1f} ({images['low']:+.1f} to {images['high']:+.1f})" in text
    assert f"an advantage above {images['high']:.1f} is ruled out" in text
    final = records["fig4"]["summary"]["final"]
    assert f"{final['no pre-training']['mean'] - final['VD']['mean']:.1f} above VD" in text

    changed = copy.deepcopy(records)
    claim = _claim(changed["fig4_rgbd"], "VD ends above L2")
    claim.update(estimate=21.25, low=11.5, high=31.0, holm_verdict="confirmed")
    grasp = _claim(changed["fig7"], "VD ends above L2 (grasping)")
    grasp.update(estimate=4.44, holm_verdict="confirmed")
    new = synthesis(changed)
    assert "VD ends above L2: +21.2 (+11.5 to +31.0)" in new and "does not end above" not in new
    assert "in grasping (+4.4)" in new.split("it ends below")[0]
    assert "holds in part on images" in new


@pytest.mark.parametrize("folder, expected", [("fig6", "Fig. 6"), ("fig4", None)])
def test_the_draws_of_the_demonstrations_are_counted_per_figure(folder, expected):
    text = synthesis(_records())
    figures = re.findall(r"except (Fig\. \d[^(]*) \(draws", text)
    assert (expected in figures) if expected else not any(f.startswith("Fig. 4") for f in figures)


def test_the_ablations_paragraph_follows_its_record():
    """Each ablation claim's effect and Holm verdict, and the plan's reading of each setting, come from the
    ablations' record; the closing sentences follow the verdicts they sum up."""
    records = _records()
    text = synthesis(records).split("\n\n")[2]
    assert text.startswith("**Where VD's wins in state mode come from.**")
    for claim in records["ablations"]["claims"]:
        effect = f"{claim['estimate']:+.1f} ({claim['low']:+.1f} to {claim['high']:+.1f}), {claim['holm_verdict']}"
        assert effect in text, claim["text"]
    for reading in records["ablations"]["reading"].values():
        assert f"the plan's reading: {reading.partition(': ')[2]}." in text

    changed = copy.deepcopy(records)
    unpruned = next(
        c for c in changed["ablations"]["claims"] if c["a"].startswith("VD without pruning") and c["b"].startswith("L2")
    )
    unpruned.update(estimate=-3.04, low=-9.0, high=2.9, holm_verdict="not confirmed")
    changed["ablations"]["reading"] = {f: f"{f}, x: pruning wins" for f in changed["ablations"]["reading"]}
    new = synthesis(changed).split("\n\n")[2]
    assert "-3.0 (-9.0 to +2.9), not confirmed" in new
    assert "The pruning is not what wins" not in new and "readings differ" not in new
