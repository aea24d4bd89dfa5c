"""The README is a doorway: short enough to read before starting, with results, long runs, differences from
the paper and the shipped data on pages of their own, and every relative link among these pages and in the
chapters' text leading to a file that exists (a moved or renamed page would otherwise leave a newcomer at a
dead end)."""
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "data" / "README.md"]

#: A Markdown link or image, ``[text](target)`` or ``![alt](target)``; the target ends at a space or ``)``.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)")


def test_readme_is_at_most_220_lines():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 220


def test_readme_links_every_page():
    readme = (ROOT / "README.md").read_text()
    for page in PAGES[1:]:
        assert f"]({page.relative_to(ROOT).as_posix()})" in readme, page


def _missing_targets(markdown: str, folder: Path) -> tuple[list[str], list[str]]:
    """The relative link targets in ``markdown`` (web addresses and in-page anchors aside), and those of them
    that name no file, resolved from ``folder``."""
    text = re.sub(r"```.*?```", "", markdown, flags=re.S)  # code blocks hold commands, not links
    targets = [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:|#", t)]
    return targets, [t for t in targets if not (folder / t.split("#", 1)[0]).exists()]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_point_to_existing_files(page):
    targets, missing = _missing_targets(page.read_text(), page.parent)
    assert targets or page.name != "README.md"
    assert not missing, f"{page.relative_to(ROOT)} links to missing files: {missing}"


@pytest.mark.parametrize("notebook", sorted((ROOT / "notebooks").glob("*.ipynb")), ids=lambda p: p.name)
def test_chapters_link_to_existing_files(notebook):
    cells = json.loads(notebook.read_text())["cells"]
    markdown = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    _, missing = _missing_targets(markdown, notebook.parent)
    assert not missing, f"{notebook.name} links to missing files: {missing}"


def test_the_exercise_count_the_guides_quote_is_the_chapters():
    """README and TEACHING.md say how many graded exercises and points the chapters hold: count them."""
    cells = [cell.get("metadata", {}).get("nbgrader", {}) for path in (ROOT / "notebooks").glob("*.ipynb")
             for cell in json.loads(path.read_text())["cells"]]
    graded = [cell["points"] for cell in cells if cell.get("grade") and cell.get("points")]
    quoted = f"{len(graded)} graded exercises ({sum(graded):g} points)"
    assert quoted in (ROOT / "README.md").read_text()
    assert f"{len(graded)} exercises worth {sum(graded):g} points" in (ROOT / "notebooks" / "TEACHING.md").read_text()


def test_data_readme_names_every_results_folder():
    """Every folder of shipped results has a row in data/README.md saying what made it."""
    readme = (ROOT / "data" / "README.md").read_text()
    folders = sorted(p.name for p in (ROOT / "data" / "results").iterdir() if p.is_dir())
    assert folders and [f for f in folders if f"`results/{f}/" not in readme] == []
