"""The book's notation (issue 42): one meaning per symbol, written down once in chapter 00's notation table.

The table's rows say what each Greek symbol means and in which chapters it appears. The tests read every
chapter's markdown and check that each Greek symbol it uses has a row that names that chapter, so a symbol
cannot quietly take a second meaning in a new chapter: using it anywhere else means adding the chapter to
its row, that is, reading the row's meaning. The letter pi is the one letter with two rows, kept apart by
how it is written: a policy always carries a subscript or an argument, the number appears alone.

A second test keeps out the collisions the book had before the table (the same letter for the KL warm-up,
TRPO's step and DAgger's mixture, and so on): each is written as a pattern of the old usage.
"""

import re
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
GREEK = (
    "alpha beta gamma delta epsilon varepsilon zeta eta theta vartheta iota kappa lambda mu nu xi pi rho "
    "varrho sigma varsigma tau upsilon phi varphi chi psi omega Gamma Delta Theta Lambda Xi Pi Sigma Phi Psi "
    "Omega"
).split()
UNICODE = dict(
    zip(
        "αβγδεζηθικλμνξπρστυφχψωΓΔΘΛΞΠΣΦΨΩ",
        "alpha beta gamma delta epsilon zeta eta theta iota kappa lambda mu nu xi pi rho sigma tau "
        "upsilon phi chi psi omega Gamma Delta Theta Lambda Xi Pi Sigma Phi Psi Omega".split(),
    )
)
TOKEN = re.compile(
    r"\\(" + "|".join(sorted(GREEK, key=len, reverse=True)) + r")(?![A-Za-z])(\s*[_(])?|([" + "".join(UNICODE) + r"])"
)

#: Usages the book had before the notation table, each now written with its own symbol (the table's notes).
OLD_USAGES = {
    r"\\beta\s*(?:=\s*\\sqrt|\\,?\s*[su]\b|F\^)": "TRPO's step scale is eta, not beta",
    r"\\beta_[ik0]|\\beta\^[ik]": "DAgger's mixture is xi, not beta",
    r"\\Sigma_\\alpha|\\alpha\\,\\hat\\Sigma|prior \$\\alpha\$": "DART's total error is bar e, not alpha",
    r"\\mathcal\{N\}\(\s*\\theta|\\theta_\{ij\}|\\log\\theta\^2|\\theta\s*\\odot": (
        "a weight's mean is bar w, not theta"
    ),
    r"\\log\s*\\sigma\^2|\\sigma\^2_\{ij\}|\\sigma_\{ij\}": "a weight's variance is omega^2, not sigma^2",
    r"\\lambda\^2\s*I|damping \$\\lambda\$": "the IK damping is zeta, not lambda",
    r"\\lambda\s*\\sum|\\lambda\s*=\s*\\texttt": "the L2 coefficient is kappa, not lambda",
    r"\\delta_t": "the TD residual is tilde r_t, not delta_t",
    r"\\gamma\s*\+\s*\\log 2": "Euler's constant is not gamma (gamma is the discount)",
    r"\\xi\s*\\sim|p\(\\xi": "a trajectory is tau, not xi (xi is DAgger's mixture)",
    r"s\^\\top F s|finds \$s\$|\$\|s\|\$": "TRPO's direction is u, not s (s is a state)",
}


def _markdown(path: Path) -> str:
    cells = nbformat.read(path, as_version=4).cells
    return "\n".join(
        c.source for c in cells if c.cell_type == "markdown" and c.get("id") not in ("notation", "glossary")
    )


def _symbols(text: str) -> set[str]:
    """The Greek symbols of a text; pi is "pi" alone (the number) and "pi_" with a subscript or argument."""
    found = set()
    for match in TOKEN.finditer(text):
        name = match.group(1) or UNICODE[match.group(3)]
        found.add("pi_" if name == "pi" and match.group(2) else name)
    return found


def notation_table() -> dict[str, set[str]]:
    """symbol -> the chapters its row names, from chapter 00's notation cell."""
    cells = nbformat.read(ROOT / "notebooks" / "00_start_here.ipynb", as_version=4).cells
    table = next(c.source for c in cells if c.get("id") == "notation")
    rows = {}
    for line in table.splitlines():
        parts = [p.strip() for p in line.strip().strip("|").split("|")]
        if len(parts) < 4 or not parts[0].startswith("$"):
            continue
        symbols = _symbols(re.sub(r"_\{?\\[A-Za-z]+", "", parts[0])) - ({"pi"} if "_" in parts[0] else set())
        if "alone" in parts[0]:
            symbols = {"pi"}
        for symbol in symbols:
            assert symbol not in rows, f"{symbol} has two rows in the notation table"
            rows[symbol] = set(parts[3].split())
    return rows


def test_the_notation_table_has_one_row_per_symbol():
    rows = notation_table()
    assert {"alpha", "beta", "theta", "sigma", "eta", "rho", "xi", "omega", "lambda", "delta", "pi", "pi_"} <= set(rows)


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=lambda p: p.stem)
def test_each_greek_symbol_is_used_as_its_row_says(notebook):
    rows, chapter = notation_table(), notebook.stem.split("_")[0]
    missing = sorted(s for s in _symbols(_markdown(notebook)) if chapter not in rows.get(s, ()))
    assert not missing, (
        f"chapter {chapter} uses {missing}: add the chapter to the symbol's row in 00's notation "
        "table if it means the same there, else use another symbol"
    )


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=lambda p: p.stem)
def test_the_old_collisions_are_gone(notebook):
    text = _markdown(notebook)
    found = [why for pattern, why in OLD_USAGES.items() if re.search(pattern, text)]
    assert not found, found


def test_the_checks_catch_a_second_meaning():
    assert _symbols(r"$\beta = \sqrt{2}$, $\pi_\theta$ and $\pi/5$, α") == {"beta", "pi_", "theta", "pi", "alpha"}
    assert re.search(next(iter(OLD_USAGES)), r"$\beta = \sqrt{2\delta / u^\top F u}$")
    assert "09" not in notation_table()["beta"]
