"""No module of the package tells its own history in a docstring or comment: the issue that changed it, the date it
was measured, the numbers that were measured. Those belong in docs/ (results.md's "Measurements behind the code",
differences.md), which a docstring may point to; the code says what it does and why.

What counts: an issue number of this project (another project's issue, cited as ``owner/name issue N``, is a
reference), a date, the word "Measured" reporting a measurement, and a measured quantity (a number with a unit of
time or size, or a speed-up). A citation's year ("Schulman et al., 2015") is a reference, not a date."""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import vdtutorial

PACKAGE = Path(vdtutorial.__file__).parent
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.relative_to(PACKAGE).parts[0] != "book")
MONTHS = "January|February|March|April|May|June|July|August|September|October|November|December"
HISTORY = re.compile(
    r"(?P<issue>\b[Ii]ssues? #?\d+)"
    rf"|\b(?:{MONTHS}) \d{{4}}\b|\b\d{{4}}-\d{{2}}-\d{{2}}\b"
    r"|\bMeasured\b|\b[Mm]easured(?::| on\b)|\([Mm]easured\b"
    r"|\b\d+(?:\.\d+)?\s?(?:ms|s|min|kB|MB|GB)\b"
    r"|\b\d+(?:\.\d+)?x (?:faster|slower|cheaper|less|more)\b"
)
#: Another project's issue, cited by its repository: "ray-project/ray issue 123".
CITED_REPOSITORY = re.compile(r"[\w.-]+/[\w.-]+\s+$")


def docstrings_and_comments(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every docstring and comment of ``path``."""
    source = path.read_text()
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, kinds) and ast.get_docstring(node, clean=False):
            found.append((node.body[0].lineno, ast.get_docstring(node, clean=False)))
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            found.append((token.start[0], token.string))
    return found


def history_in(text: str) -> list[str]:
    """What in ``text`` names an issue, a date or a measurement (module docstring)."""
    found = []
    for match in HISTORY.finditer(text):
        if match.group("issue") and CITED_REPOSITORY.search(text[: match.start()]):
            continue
        found.append(match.group(0))
    return found


def offences() -> dict[str, list[str]]:
    """``{module: ["line N: 'what'", ...]}`` for every module of the package that tells history."""
    found = {}
    for path in MODULES:
        lines = [f"line {line}: {what!r}" for line, text in docstrings_and_comments(path) for what in history_in(text)]
        if lines:
            found[str(path.relative_to(PACKAGE))] = lines
    return found


def test_the_pattern_tells_history_from_reference():
    assert history_in("the faster kernel (issue 31), measured on 2026-12-03: 104 ms instead of 162 ms, 1.6x faster")
    assert len(history_in("Measured with the defaults (200 epochs, ~16-20 s); see Issue #12 of March 2026")) == 4
    assert history_in("(measured: 100% of the image stream's weights dropped)")
    assert not history_in("Schulman et al., 2015, eq. 12; a timeout (ray-project/ray issue 65983)")
    assert not history_in("the expert measured as a reference line, 200 steps per episode, sigma 0.3 rad")


def test_no_module_names_an_issue_a_date_or_a_measurement():
    found = offences()
    assert not found, "history in docstrings or comments (move it to docs/):\n" + "\n".join(
        f"{module}: {'; '.join(lines)}" for module, lines in sorted(found.items())
    )
