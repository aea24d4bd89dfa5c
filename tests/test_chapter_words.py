"""A chapter quotes our measured results only through its cells: a number typed into markdown goes stale the
moment the result is made again, and a learner cannot tell which of the two is wrong.

The test collects every decimal number written in the chapters' markdown and fails when one of them equals,
as written, a measured value of a shipped result record (``data/results/**/*.json``: the summary's final
levels, the claims' estimates and bounds, the sigma study's per-option means, each run's seconds, the wall
time; the settings under ``*_config`` keys are left out) or of a shipped table (``data/results/**/*.csv``:
Table I's measured sparsities; columns named ``*_paper`` hold the paper's values and are left out), rounded
to the same number of decimals. The per-iteration curves (``*.csv.gz``) are left out: hundreds of thousands of
raw values would match any decimal, and a chapter quotes what they sum up, which the records hold. The rule
is narrow on purpose, so that the paper's constants and the library's settings pass:

* only numbers with a decimal point count (``3e5``, ``log alpha > 3``, ``25 iterations`` never do), and
  nothing in scientific notation;
* only numbers with at least three significant digits count (``0.05``, ``0.3``, ``1.0`` are settings, not
  results; ``75.5`` or ``2.81`` are results).

It also checks that each chapter numbers its exercises in the order a learner meets them (across the
notebooks of a chapter in parts, such as 06a and 06b).
"""

import ast
import csv
import json
import math
import re
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
#: A plain decimal such as 75.5 or -4.87, not part of a longer token (a version 2.13.0, 2.81e5, x1.5) nor the
#: mantissa of a number in scientific notation written in TeX (1.25\mathrm{e}5, 2.81\cdot10^5, 3 \times 10^5), nor
#: an exercise's number (Exercise 10.1).
DECIMAL = re.compile(r"(?<![\w.])(?<!Exercise )-?\d+\.\d+(?![\w.]|\s*\\(?:mathrm\{e\}|cdot|times))")


def _significant_digits(text: str) -> int:
    return len(text.lstrip("-").replace(".", "").lstrip("0"))


def _floats(tree):
    """Every non-integer number in a JSON tree (integers are counts: seeds, steps, iterations), but the
    settings a run was made with (``pretrain_config``, ``trpo_config``)."""
    if isinstance(tree, dict):
        for key, value in tree.items():
            if not key.endswith("_config"):
                yield from _floats(value)
    elif isinstance(tree, list):
        for value in tree:
            yield from _floats(value)
    elif isinstance(tree, float) and math.isfinite(tree) and not tree.is_integer():
        yield tree


def _table_floats(path: Path):
    """The measured non-integer numbers of a shipped table (the paper's columns left out)."""
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            for column, text in row.items():
                try:
                    value = float(text)
                except (TypeError, ValueError):
                    continue
                if not column.endswith("_paper"):
                    yield from _floats(value)


def shipped_results() -> dict[float, str]:
    """Each measured value of each shipped result record and each measured number of each shipped table, with
    the file it comes from."""
    from vdtutorial.course.chapters import shipped_files

    found = {}
    shipped = [ROOT / path for path in shipped_files(ROOT) if path.parts[:2] == ("data", "results")]
    for path in [p for p in shipped if p.suffix == ".json"]:
        for value in _floats(json.loads(path.read_text())):
            found.setdefault(value, str(path.relative_to(ROOT)))
    for path in [p for p in shipped if p.suffix == ".csv"]:
        for value in _table_floats(path):
            found.setdefault(value, str(path.relative_to(ROOT)))
    return found


def typed_results(markdown: str, results: dict[float, str]) -> list[str]:
    """The decimals in ``markdown`` that equal a result, rounded as written, each with the result's file."""
    hits = []
    for number in DECIMAL.findall(markdown):
        if _significant_digits(number) < 3:
            continue
        decimals = len(number.split(".")[1])
        for value, source in results.items():
            if f"{value:.{decimals}f}" == number:
                hits.append(f"{number} ({source}: {value})")
                break
    return hits


def test_the_rule_catches_a_typed_result_and_passes_settings():
    results = {75.48799999999999: "fig4.json", 0.0512: "x.json"}
    assert typed_results("VD ends at 75.5 successes", results) == ["75.5 (fig4.json: 75.48799999999999)"]
    assert typed_results("VD ends at 75.49", results) == ["75.49 (fig4.json: 75.48799999999999)"]
    # settings and paper constants: too few significant digits, scientific notation, integers, versions
    assert typed_results("sigma 0.05, 3e5 steps, 7.55e1, log alpha > 3, 75 successes, torch 2.75.5", results) == []
    assert typed_results(r"$75.49\mathrm{e}5$, $75.49\cdot10^5$, $75.49 \times 10^5$", results) == []
    assert typed_results("### Exercise 75.49: a title", results) == []


def test_the_shipped_results_have_summaries():
    assert len(shipped_results()) > 100


#: Numbers typed in markdown that are not results but coincide with one (the success rate and steps per
#: trajectory of the shipped summaries lie near 1 and 3): (chapter, cell id) -> the numbers, each with why.
NOT_RESULTS = {
    ("00_start_here", "c003"): {"3.11", "3.12", "3.13"},  # Python versions
    ("04_sparse_variational_dropout", "c011"): {"0.9997"},  # the dropout rate at log alpha = 8, a constant
    ("07_finetuning", "606f7cb1"): {"0.975"},  # Student's t: the quantile's level, a constant
}


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=[nb.stem for nb in NOTEBOOKS])
def test_no_markdown_cell_types_a_measured_result(notebook):
    results = shipped_results()
    typed = {}
    for cell in nbformat.read(notebook, as_version=4).cells:
        allowed = NOT_RESULTS.get((notebook.stem, cell.get("id")), set())
        if cell.cell_type == "markdown" and (
            hits := [hit for hit in typed_results(cell.source, results) if hit.split(" ")[0] not in allowed]
        ):
            typed[cell.get("id")] = hits
    assert not typed, f"{notebook.name}: results typed into markdown (print them from a cell): {typed}"


#: The chapters by number: a chapter in parts (06a_..., 06b_...) is its notebooks in the order they sort.
CHAPTERS = {
    number: [nb for nb in NOTEBOOKS if nb.stem[:2] == number] for number in sorted({nb.stem[:2] for nb in NOTEBOOKS})
}


@pytest.mark.parametrize("number", CHAPTERS)
def test_exercises_are_numbered_in_the_order_they_come(number):
    """N.1, N.2, ... in the order a learner meets them, continuing from one part of a chapter to the next."""
    numbers = [
        tuple(map(int, m))
        for notebook in CHAPTERS[number]
        for cell in nbformat.read(notebook, as_version=4).cells
        if cell.cell_type == "markdown"
        for m in re.findall(r"^#+ Exercise (\d+)\.(\d+)\b", cell.source, flags=re.MULTILINE)
    ]
    expected = [(int(number), k) for k in range(1, len(numbers) + 1)]
    parts = ", ".join(nb.name for nb in CHAPTERS[number])
    assert numbers == expected, f"chapter {number} ({parts}): exercises {numbers}"


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=[nb.stem for nb in NOTEBOOKS])
def test_a_question_in_an_exercise_has_a_model_answer_in_its_solution(notebook):
    """An exercise's prompt that asks a question ("Why ...?") is answered in the solution, as a comment
    ``# Why ...`` between the solution markers: the teacher's edition, and the self-learner's ``solutions/``,
    then hold a model answer, while the student edition shows only the question."""
    cells = nbformat.read(notebook, as_version=4).cells
    unanswered = []
    for prompt, answer in zip(cells, cells[1:]):
        if prompt.cell_type == "markdown" and re.match(r"#+ Exercise", prompt.source) and "?" in prompt.source:
            solution = re.search(r"### BEGIN SOLUTION\n(.*?)### END SOLUTION", answer.source, re.S)
            if not (solution and re.search(r"^\s*# Why\b", solution.group(1), re.M)):
                unanswered.append(prompt.source.splitlines()[0])
    assert not unanswered, f"{notebook.name}: questions without a model answer in the solution: {unanswered}"


def _exercises():
    """(notebook, answer cell index, the solution's lines of code) for every graded exercise of the book."""
    found = []
    for notebook in NOTEBOOKS:
        cells = nbformat.read(notebook, as_version=4).cells
        for k, cell in enumerate(cells):
            if cell.cell_type == "code" and cell.metadata.get("nbgrader", {}).get("solution"):
                solution = re.search(r"### BEGIN SOLUTION\n(.*?)### END SOLUTION", cell.source, re.S).group(1)
                code = [line for line in solution.splitlines() if line.strip() and not line.strip().startswith("#")]
                found.append((notebook, cells, k, len(code)))
    return found


def test_the_exercises_build_rather_than_transcribe():
    """Issue 42's measure of an exercise that builds: at least 12 solutions of 5 or more lines of code, and a
    median of at least 5 (comments and blank lines not counted)."""
    lengths = sorted(n for *_, n in _exercises())
    median = (lengths[(len(lengths) - 1) // 2] + lengths[len(lengths) // 2]) / 2
    assert sum(n >= 5 for n in lengths) >= 12 and median >= 5, lengths


def test_later_cells_run_what_the_learner_wrote():
    """At least 6 exercises define a function or class that a later, ungraded code cell of the same notebook
    calls, so that the learner's code drives the chapter."""
    used = []
    for notebook, cells, k, _ in _exercises():
        names = {
            node.name
            for node in ast.walk(ast.parse(cells[k].source))
            if isinstance(node, (ast.FunctionDef, ast.ClassDef))
        }
        later = "\n".join(c.source for c in cells[k + 1 :] if c.cell_type == "code" and "nbgrader" not in c.metadata)
        if any(re.search(rf"\b{name}\b", later) for name in names):
            used.append(f"{notebook.stem}: {sorted(names)}")
    assert len(used) >= 6, used
