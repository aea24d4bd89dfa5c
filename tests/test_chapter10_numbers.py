"""Every number chapter 10 prints in its sentences is its record's: the cells that print them run here (the verdict
counts and lists, what each figure rests on, the synthesis), and each paragraph's numbers are compared, as a
multiset, with the numbers this test computes itself from the shipped records -- the JSON records for claims,
estimates, intervals and verdict counts, and the rows (the CSVs) for seeds per method, budgets and data sets. A number
that is not its record's, or one that is missing or left over, fails. The last test alters one record in a copy and
shows the check failing on the chapter's text from the unaltered records."""

from __future__ import annotations

import contextlib
import copy
import functools
import io
import json
import re
import shutil
from collections import Counter
from pathlib import Path

import pytest

from vdtutorial.runner import read_rows, results_file
from vdtutorial.settings import data_dir

ROOT = Path(__file__).resolve().parents[1]
CHAPTER = ROOT / "notebooks" / "10_what_reproduced.ipynb"
#: The records chapter 10 reads: its headings and folders (the chapter's FIGURES), checked against the chapter below.
HEADINGS = {
    "Fig. 4, state": "fig4",
    "Fig. 4, images": "fig4_rgbd",
    "Fig. 5, state": "fig5",
    "Fig. 6, state": "fig6",
    "Fig. 6, state, 2nd draw": "fig6_demos1",
    "Fig. 7, state": "fig7",
}
#: A number in running text: not inside a word (L2, Fig5) or a longer number; thousands may be grouped by commas.
NUMBER = re.compile(r"(?<![\w.])[+-]?\d{1,3}(?:,\d{3})+(?![\d])|(?<![\w.])[+-]?\d+(?:\.\d+)?(?:e[+-]?\d+)?(?![\w])")


def numbers(text: str) -> Counter:
    """The numbers of ``text`` as a multiset, a leading "+" and thousands commas dropped ("+3.3" and "3.3" are one)."""
    return Counter(token.lstrip("+").replace(",", "") for token in NUMBER.findall(text))


#: The ablations' record, which the synthesis reads beside the figures' (not a figure of the claims table).
ABLATIONS = "ablations"


def _records(root: Path) -> dict[str, dict]:
    return {
        folder: json.loads(next((root / folder).glob("*.json")).read_text())
        for folder in (*HEADINGS.values(), ABLATIONS)
    }


def _on_metric(record: dict) -> list[dict]:
    return [c for c in record["summary"]["claims"] if c["metric"] == record["metric"]]


def _claim(record: dict, text: str, measure: str = "final") -> dict:
    return next(c for c in _on_metric(record) if c["text"] == text and c["measure"] == measure)


def _effect(c: dict) -> str:
    return f"{c['estimate']:+.1f} {c['low']:+.1f} {c['high']:+.1f}"


def _demo_seed(record: dict) -> int:
    (seed,) = {run.get("demo_seed", 0) for run in record["runs"] if run["method"] not in ("none", "expert")}
    return seed


# -- what the numbers should be, from the records ----------------------------------------------------------------
def expected_synthesis(records: dict[str, dict]) -> list[str]:
    """Per paragraph of the synthesis, a string holding exactly the numbers it must print: the records' values, the
    numbers of the claims' own texts, and the fixed words (a figure's number, "per 200 steps", "80% power")."""
    images = records["fig4_rgbd"]
    final = _claim(images, "VD ends above L2")
    confirmed = [c for c in _on_metric(images) if c["holm_verdict"] == "confirmed"]
    first = [f"Fig. 4 {_effect(final)} per 200 steps {final['n_a']} above {final['high']:.1f} within 42%"]
    for c in confirmed:
        first.append(f"{c['text']} {_effect(c)} {c['n_a']} {c['n_b']}")
    for c in confirmed:
        if c.get("across_batches") and c.get("within_shared_batches"):
            w = c["within_shared_batches"]
            first.append(f"{c['text']} {_effect(w)} {w['p_value']:.2g} {w['seeds'][0]} {w['seeds'][1]}")

    second = ["per 200 steps (Fig. 4)"]
    for folder in ("fig4", "fig5", "fig6", "fig6_demos1", "fig7"):
        for c in _on_metric(records[folder]):
            if (
                c["measure"] == "final"
                and c["a"].startswith("VD")
                and c["b"].startswith("L2")
                and c["text"].startswith("VD ends above L2")
                and not c.get("same_runs")
            ):
                setting = "Fig. 4" if c["text"] == "VD ends above L2" else c["text"]
                second.append(f"{setting} {c['estimate']:+.1f}")
    levels = records["fig4"]["summary"]["final"]
    second.append(f"{levels['no pre-training']['mean'] - levels['VD']['mean']:.1f}")
    second.append(f"{levels['no pre-training']['mean'] - levels['L2']['mean']:.1f}")

    detectable = [
        c["detectable"]
        for folder in ("fig4", "fig4_rgbd", "fig5", "fig6", "fig6_demos1")
        for c in records[folder]["summary"]["claims"]
        if c["metric"] == "successes" and c["measure"] == "final" and c["text"].startswith("VD ends above L2")
    ]
    grasp = _claim(records["fig7"], "VD ends above L2 (grasping)")
    third = [f"80% {min(detectable):.1f} {max(detectable):.1f} per 200 steps {grasp['detectable']:.1f}"]
    draws: dict[str, set] = {}
    for heading, folder in HEADINGS.items():
        draws.setdefault(heading.split(",")[0], set()).add(_demo_seed(records[folder]))
    third += [f"{figure} {' '.join(map(str, sorted(s)))}" for figure, s in draws.items() if len(s) > 1]
    fig5 = _claim(records["fig5"], "VD ends above L2 with 2000 demonstrations")
    if isinstance(fig5.get("looks"), dict):
        looks = fig5["looks"]
        third.append(
            f"Fig. 5 2000 {looks['stage_seeds'][0][0]} {looks['stage_seeds'][1][0]} {looks['stage_estimates'][0]:+.1f} "
            f"{looks['stage_estimates'][1]:+.1f} {looks['combined_p_one_sided']:.2g} {fig5['p_value']:.2g}"
        )
    ablations = records[ABLATIONS]
    where = [f"{len(seeds)}" for seeds in {tuple(s) for s in ablations["seeds"].values()}] + ["per 200 steps"]
    for source in ablations["sources"]:
        where.append(f"Fig. {source['setting'].removeprefix('fig')} {source['data_set']} {source['dropout_rate']:g}")
    where += [_effect(c) for c in ablations["claims"]]
    return [" ".join(first), " ".join(second), " ".join(where), " ".join(third), ""]


def expected_counts(records: dict[str, dict]) -> str:
    """The numbers of the verdict counts and lists that the chapter prints under its claims table."""
    by_verdict: dict[str, list[str]] = {}
    for heading, folder in HEADINGS.items():
        for c in _on_metric(records[folder]):
            if c["measure"] in ("final", "steps_to_reach"):
                by_verdict.setdefault(c["holm_verdict"], []).append(f"{heading} {c['text']}")
    parts = [" ".join(str(len(rows)) for rows in by_verdict.values())]
    finals = [c for folder in HEADINGS.values() for c in _on_metric(records[folder]) if c["measure"] == "final"]
    kinds = ("confirmed", "contradicted", "not confirmed", "negligible")
    for rows in (finals, [c for c in finals if not c.get("same_runs")]):
        parts.append(f"{len(rows)} " + " ".join(str(sum(c["holm_verdict"] == kind for c in rows)) for kind in kinds))
    parts += [" ".join(by_verdict.get(kind, [])) for kind in ("confirmed", "contradicted", "negligible")]
    parts.append("Fig. 6")  # "Fig. 6 on two draws of the demonstrations"
    return " ".join(parts)


@functools.cache
def _rows(folder: str, experiment: str) -> list[dict]:
    return read_rows(results_file(data_dir() / "results" / folder, experiment))


def expected_foundations(records: dict[str, dict]) -> dict[str, str]:
    """What each figure rests on, by heading, from its rows (the CSVs): the longest run's env steps, the data sets, and
    per curve the number of seeds that have rows; the window from the record."""
    parts = {}
    for heading, folder in HEADINGS.items():
        record = records[folder]
        rows = _rows(folder, record["experiment"])
        trained = [r for r in rows if r["method"] != "expert"]
        steps = max(int(r["env_steps"]) for r in trained)
        data = sorted({(int(r["samples"]), float(r["noise"])) for r in trained if r["samples"] not in ("", None)})
        seeds: dict[str, set] = {}
        for r in rows:
            seeds.setdefault(r["label"], set()).add(int(r["seed"]))
        fragments = [f"{heading} ", f"{steps:,}", f"last {record['window']} iterations"]
        fragments.append(", ".join(f"{n} / {s:g}" for n, s in data))
        fragments += [f"{label} {len(s)}" for label, s in seeds.items()]
        parts[heading] = fragments
    return parts


# -- what the chapter prints ------------------------------------------------------------------------------------
def _cell(cells: list[dict], *marks: str) -> str:
    (source,) = [
        "".join(c["source"])
        for c in cells
        if c["cell_type"] == "code" and all(m in "".join(c["source"]) for m in marks)
    ]
    return source


def chapter_output(results: Path) -> dict[str, str]:
    """Run chapter 10's cells that print sentences, reading the records under ``results``: what each printed, and the
    synthesis it displayed."""
    cells = json.loads(CHAPTER.read_text())["cells"]
    namespace: dict = {}
    exec(_cell(cells, "RESULTS = data_dir()"), namespace)
    shown: list = []
    namespace.update(RESULTS=results, display=shown.append)
    out = {}
    for name, marks in (
        ("counts", ("Holm verdicts on the paper's metric",)),
        ("foundations", ("seeds per method",)),
        ("synthesis", ("synthesis(",)),
    ):
        printed = io.StringIO()
        shown.clear()
        with contextlib.redirect_stdout(printed):
            exec(_cell(cells, *marks), namespace)
        out[name] = printed.getvalue()
        if name == "synthesis":
            (markdown,) = shown
            out[name] = markdown.data
    return out


def mismatches(printed: dict[str, str], records: dict[str, dict]) -> list[str]:
    """Where the printed numbers and the records' differ: per paragraph, the numbers missing from the text and the
    numbers the text has that its records do not give."""
    found = []
    paragraphs = printed["synthesis"].split("\n\n")
    expected = expected_synthesis(records)
    if len(paragraphs) != len(expected):
        return [f"the synthesis has {len(paragraphs)} paragraphs, expected {len(expected)}"]
    pairs = [*zip(paragraphs, expected), (printed["counts"], expected_counts(records))]
    blocks = re.split(r"\n(?=\S)", printed["foundations"].strip())  # a header line, then two lines per figure
    if [block.split("  ")[0] for block in blocks[1:]] != list(HEADINGS):
        return [f"what each figure rests on is printed for {[b.split('  ')[0] for b in blocks[1:]]}"]
    for block, fragments in zip(blocks[1:], expected_foundations(records).values()):
        pairs.append((block, " ".join(fragments)))
        # each in its place: a seed count beside its own curve's label, followed by the next label or the line's end
        found += [
            f"{block[:30]!r}...: no {fragment!r}"
            for fragment in fragments
            if not re.search(re.escape(fragment) + r"(?=,|\s|$)", block)
        ]
    for text, want in pairs:
        have, need = numbers(text), numbers(want)
        if have != need:
            found.append(f"{text[:60]!r}...: missing {dict(need - have)}, not from the records {dict(have - need)}")
    return found


@pytest.fixture(scope="module")
def shipped_output() -> dict[str, str]:
    return chapter_output(data_dir() / "results")


def test_the_chapter_reads_the_records_this_test_reads():
    cells = json.loads(CHAPTER.read_text())["cells"]
    namespace: dict = {}
    exec(_cell(cells, "Holm verdicts on the paper's metric").split("\nrecords =")[0], namespace)
    assert namespace["FIGURES"] == HEADINGS


def test_every_number_chapter_10_prints_is_its_records(shipped_output):
    assert shipped_output["synthesis"].count("\n\n") == 4 and "seeds per method" in shipped_output["foundations"]
    assert mismatches(shipped_output, _records(data_dir() / "results")) == []


def test_a_number_that_differs_from_its_record_fails(shipped_output, tmp_path):
    """A copy of the records with one estimate changed: the chapter's text from the shipped records no longer matches
    them, and the chapter run on the copy prints the new number and matches. A number typed into a sentence, and two
    seed counts swapped between curves, fail too."""
    for folder in (*HEADINGS.values(), ABLATIONS):
        shutil.copytree(data_dir() / "results" / folder, tmp_path / folder, ignore=shutil.ignore_patterns("*.png"))
    altered = copy.deepcopy(_records(tmp_path))
    claim = _claim(altered["fig4_rgbd"], "VD ends above L2")
    claim["estimate"] += 1.0
    path = next((tmp_path / "fig4_rgbd").glob("*.json"))
    path.write_text(json.dumps(altered["fig4_rgbd"]))
    found = mismatches(shipped_output, altered)
    assert len(found) == 1 and "In the paper's own setting" in found[0]
    moved = f"{claim['estimate']:+.1f}".lstrip("+")
    assert moved in found[0]

    rerun = chapter_output(tmp_path)
    assert mismatches(rerun, altered) == []
    assert rerun["synthesis"] != shipped_output["synthesis"]

    shipped = _records(data_dir() / "results")
    typed = dict(shipped_output, synthesis=shipped_output["synthesis"].replace("80% power", "90% power"))
    assert any("90" in line for line in mismatches(typed, shipped))
    # two curves' seed counts swapped on one line (the first line whose curves have different counts)
    counts = [
        (line, re.findall(r"([A-Za-z0-9 .,-]+?) (\d+)(?=,|$)", line.split("seeds per method: ")[1]))
        for line in shipped_output["foundations"].splitlines()
        if "seeds per method: " in line
    ]
    line, curves = next((line, curves) for line, curves in counts if len({n for _, n in curves}) > 1)
    (a, n), (b, m) = curves[0], next(c for c in curves if c[1] != curves[0][1])
    a, b = a.lstrip(", "), b.lstrip(", ")
    swapped = line.replace(f"{a} {n}", f"{a} {m}", 1).replace(f"{b} {m}", f"{b} {n}", 1)
    moved = dict(shipped_output, foundations=shipped_output["foundations"].replace(line, swapped))
    assert any(f"no '{b} {m}'" in x for x in mismatches(moved, shipped))  # the same numbers, misplaced
