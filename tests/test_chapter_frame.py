"""Every main chapter opens and closes the same way: goals, prerequisites and time first; a self-check of at least
three questions with their answers folded in ``<details>``, and the library names the chapter uses, last.

The reading time is checked against the chapter's own words (200 a minute, to the nearest 5 minutes), so it
cannot go stale when the text changes."""
import re
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
CHAPTERS = sorted((ROOT / "notebooks").glob("[0-9][0-9]*.ipynb"))
WORDS_PER_MINUTE = 200


def _markdown(notebook) -> list:
    return [cell for cell in notebook.cells if cell.cell_type == "markdown"]


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_chapter_opens_with_goals_prerequisites_and_time(path):
    notebook = nbformat.read(path, as_version=4)
    opening = notebook.cells[1]
    assert opening.get("id") == "chapter-goals" and opening.cell_type == "markdown", "the cell after the title"
    goals = re.search(r"\*\*After this chapter you can\*\*\n\n((?:\* .+\n?)+)", opening.source)
    assert goals and 3 <= len(goals.group(1).strip().splitlines()) <= 5, "3-5 learning goals"
    assert re.search(r"\*\*Prerequisites\.\*\* \S.{10,}", opening.source)
    minutes = int(re.search(r"\*\*Time\.\*\* About (\d+) minutes of reading", opening.source).group(1))
    words = sum(len(re.findall(r"\S+", cell.source)) for cell in _markdown(notebook))
    assert minutes == max(5, 5 * round(words / WORDS_PER_MINUTE / 5)), f"{words} words"
    assert "**Library names in this" not in notebook.cells[0].source, "library names go in the footer"


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_chapter_closes_with_a_self_check_whose_answers_are_folded(path):
    notebook = nbformat.read(path, as_version=4)
    closing = _markdown(notebook)[-1]
    assert closing.get("id") == "self-check" and closing.source.startswith("## Self-check\n")
    questions = re.findall(r"^\d+\. (.+?)\n\n\s*<details><summary>Answer</summary>\n\n\s*(\S.+?)\n\n\s*</details>",
                           closing.source, flags=re.MULTILINE | re.DOTALL)
    assert len(questions) >= 3 and all(q.endswith("?") and len(a) > 40 for q, a in questions), questions
    assert closing.source.count("<details>") == closing.source.count("</details>") == len(questions)
    assert "**Library names in this" in closing.source, "the footer names the library functions the chapter uses"


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_chapter_states_the_run_times_that_teaching_md_measured(path):
    """The first code cell's comment gives the chapter's run time in both modes: the numbers of TEACHING.md's
    "Time per chapter" table, so that the two never disagree."""
    comment = next(cell.source for cell in nbformat.read(path, as_version=4).cells if cell.cell_type == "code")
    quick = re.search(r"\(this chapter: ([\d.]+ (?:s|min)) on a quiet 2-core machine\)", comment).group(1)
    full = re.search(r"\(this chapter: ([\d.]+ (?:s|min)) on the same machine;", comment).group(1)
    teaching = (ROOT / "notebooks" / "TEACHING.md").read_text()
    number = path.stem.split("_")[0]
    assert re.search(rf"^\| {number} [^|]+\| {re.escape(quick)} \| {re.escape(full)} \|$", teaching, re.MULTILINE), \
        (quick, full)
