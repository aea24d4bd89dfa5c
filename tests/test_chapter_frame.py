"""Every main chapter opens and closes the same way: goals, prerequisites and time first; a self-check of at least
three questions with their answers folded in ``<details>``, and the library names the chapter uses, last.

The reading time is checked against the chapter's own words (200 a minute, to the nearest 5 minutes), so it
cannot go stale when the text changes. A main chapter keeps at most 3,500 words of prose: the project's own
quality control (studies of our free choices, the statistics of verdicts, release histories) lives in the
appendices (``notebooks/A<k>_*.ipynb``), which a main chapter links where the question comes up and which run
on their own like the chapters."""

import re
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
CHAPTERS = sorted((ROOT / "notebooks").glob("[0-9][0-9]*.ipynb"))
APPENDICES = sorted((ROOT / "notebooks").glob("A[0-9]_*.ipynb"))
WORDS_PER_MINUTE = 200
#: The most prose a main chapter holds (issue 42); the deep dives go to the appendices.
MAX_CHAPTER_WORDS = 3500


def _markdown(notebook) -> list:
    return [cell for cell in notebook.cells if cell.cell_type == "markdown"]


def _words(notebook) -> int:
    return sum(len(re.findall(r"\S+", cell.source)) for cell in _markdown(notebook))


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_main_chapter_keeps_at_most_3500_words_of_prose(path):
    assert _words(nbformat.read(path, as_version=4)) <= MAX_CHAPTER_WORDS


def test_the_book_has_appendices():
    assert len(APPENDICES) >= 3, [p.name for p in APPENDICES]


@pytest.mark.parametrize("path", APPENDICES, ids=lambda p: p.stem)
def test_an_appendix_is_linked_from_a_main_chapter_and_links_back(path):
    """An appendix is reached from the place in a chapter where its question comes up, says what it is for
    under its title, and leads back; it has no exercises (the graded path is the chapters)."""
    notebook = nbformat.read(path, as_version=4)
    key = path.name.split("_")[0]
    title = notebook.cells[0]
    assert title.cell_type == "markdown" and re.match(rf"# {key} · \S", title.source), "'# A<k> · title' first"
    assert len(re.findall(r"\S+", title.source)) >= 30, "the title cell says what the appendix answers"
    linking = [
        chapter.name
        for chapter in CHAPTERS
        if any(f"]({path.name}" in cell.source for cell in _markdown(nbformat.read(chapter, as_version=4)))
    ]
    assert linking, "no main chapter links this appendix"
    back = re.findall(r"\]\((\d\d[a-z]?_[\w]+\.ipynb)", "".join(cell.source for cell in _markdown(notebook)))
    assert back and all((ROOT / "notebooks" / name).exists() for name in back), "no link back to a chapter"
    assert not [cell for cell in notebook.cells if cell.get("metadata", {}).get("nbgrader", {}).get("grade")]


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_chapter_opens_with_goals_prerequisites_and_time(path):
    notebook = nbformat.read(path, as_version=4)
    opening = notebook.cells[1]
    assert opening.get("id") == "chapter-goals" and opening.cell_type == "markdown", "the cell after the title"
    goals = re.search(r"\*\*After this chapter you can\*\*\n\n((?:\* .+\n?)+)", opening.source)
    assert goals and 3 <= len(goals.group(1).strip().splitlines()) <= 5, "3-5 learning goals"
    assert re.search(r"\*\*Prerequisites\.\*\* \S.{10,}", opening.source)
    minutes = int(re.search(r"\*\*Time\.\*\* About (\d+) minutes of reading", opening.source).group(1))
    words = _words(notebook)
    assert minutes == max(5, 5 * round(words / WORDS_PER_MINUTE / 5)), f"{words} words"
    assert "**Library names in this" not in notebook.cells[0].source, "library names go in the footer"


@pytest.mark.parametrize("path", CHAPTERS, ids=lambda p: p.stem)
def test_a_chapter_closes_with_a_self_check_whose_answers_are_folded(path):
    notebook = nbformat.read(path, as_version=4)
    closing = _markdown(notebook)[-1]
    assert closing.get("id") == "self-check" and closing.source.startswith("## Self-check\n")
    questions = re.findall(
        r"^\d+\. (.+?)\n\n\s*<details><summary>Answer</summary>\n\n\s*(\S.+?)\n\n\s*</details>",
        closing.source,
        flags=re.MULTILINE | re.DOTALL,
    )
    assert len(questions) >= 3 and all(q.endswith("?") and len(a) > 40 for q, a in questions), questions
    assert closing.source.count("<details>") == closing.source.count("</details>") == len(questions)
    assert "**Library names in this" in closing.source, "the footer names the library functions the chapter uses"


@pytest.mark.parametrize("path", CHAPTERS + APPENDICES, ids=lambda p: p.stem)
def test_a_chapter_states_the_run_times_that_teaching_md_measured(path):
    """The first code cell's comment gives the chapter's (or appendix's) run time in both modes: the numbers of
    TEACHING.md's "Time per chapter" table, so that the two never disagree."""
    comment = next(
        cell.source
        for cell in nbformat.read(path, as_version=4).cells
        if cell.cell_type == "code" and cell.get("id") != "colab-setup"
    )  # the Colab cell comes first
    quick = re.search(r"\(this (?:chapter|appendix): ([\d.]+ (?:s|min)) on a quiet 2-core machine\)", comment).group(1)
    full = re.search(r"\(this (?:chapter|appendix): ([\d.]+ (?:s|min)) on the same machine;", comment).group(1)
    teaching = (ROOT / "notebooks" / "TEACHING.md").read_text()
    number = path.stem.split("_")[0]
    assert re.search(rf"^\| {number} [^|]+\| {re.escape(quick)} \| {re.escape(full)} \|$", teaching, re.MULTILINE), (
        quick,
        full,
    )


def test_the_browser_test_drives_every_notebook_with_a_slider():
    """tests/test_lab.py moves every slider of the notebooks it lists in a real JupyterLab: a slider that moves
    to another notebook (an appendix) must move into that list too."""
    from test_lab import CHAPTERS as LAB_CHAPTERS

    sliders = {}
    for path in CHAPTERS + APPENDICES:
        code = "".join(cell.source for cell in nbformat.read(path, as_version=4).cells if cell.cell_type == "code")
        if re.findall(r"\w*Slider\(", code):
            sliders[path.stem] = len(re.findall(r"\w*Slider\(", code))
    assert sliders == {chapter: n for chapter, n in LAB_CHAPTERS.items() if n}
