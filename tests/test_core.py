"""The library's core is the paper's method and nothing else: the modules directly in ``vdtutorial/`` (with
``envs/``) are the ones a learner reads beside the chapters, and they import only each other. The speed-ups,
the experiments, the grid runner, the course and the command line sit in subpackages that may import the
core, never the other way round.

Two lists record what has not moved yet: they may only shrink. A module that leaves the top level, or an
import that is cut, must be struck from its list (the tests say so), so the boundary never slips back."""
from __future__ import annotations

import ast
import io
import os
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import vdtutorial

PACKAGE = Path(vdtutorial.__file__).parent
#: The method, in the order the chapters teach it.
CORE = ("settings", "envs", "expert", "demos", "vd", "policy", "methods", "pretrain", "trust_region", "baselines",
        "rollout", "trpo")
#: Top-level modules that are not the method and still wait for their subpackage.
NOT_YET_MOVED: set[str] = set()
#: Imports from a core module to outside the core that are still to be cut: (module, what it imports).
KNOWN_IMPORTS: set[tuple[str, str]] = set()


def _top_level() -> set[str]:
    return {p.stem for p in PACKAGE.glob("*.py") if p.stem not in ("__init__", "__main__")} | {"envs"}


def _core_files() -> list[Path]:
    return sorted(p for name in CORE for p in ([PACKAGE / f"{name}.py"] if name != "envs"
                                               else (PACKAGE / "envs").glob("*.py")))


def _imports(path: Path) -> set[str]:
    """The ``vdtutorial`` modules ``path`` imports, anywhere in the file (function bodies too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "vdtutorial":
            found.update([node.module] if node.module != "vdtutorial" else [f"vdtutorial.{a.name}" for a in node.names])
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "vdtutorial")
    return found


def _in_core(module: str) -> bool:
    parts = module.split(".")
    return len(parts) == 1 or parts[1] in CORE  # the package itself (its version) or a core module


def test_the_top_level_holds_the_method_and_the_modules_still_waiting_only():
    top = _top_level()
    assert set(CORE) <= top, f"core modules missing: {sorted(set(CORE) - top)}"
    assert top - set(CORE) <= NOT_YET_MOVED, f"not the method, at the top level: {sorted(top - set(CORE) - NOT_YET_MOVED)}"
    moved = NOT_YET_MOVED - top
    assert not moved, f"{sorted(moved)} left the top level: strike them from NOT_YET_MOVED"


def test_a_core_module_imports_only_the_core():
    crossing = {(path.stem if path.parent == PACKAGE else f"envs.{path.stem}", name)
                for path in _core_files() for name in _imports(path) if not _in_core(name)}
    assert crossing <= KNOWN_IMPORTS, f"the core imports from outside it: {sorted(crossing - KNOWN_IMPORTS)}"
    assert not KNOWN_IMPORTS - crossing, f"cut, so strike them from KNOWN_IMPORTS: {sorted(KNOWN_IMPORTS - crossing)}"


def test_the_core_runs_without_the_course_the_runner_or_the_experiments():
    """Not just the source text: a fresh interpreter that imports every core module loads no subpackage
    (the known imports aside, which are still listed above)."""
    still = sorted({name.split(".")[1] for _, name in KNOWN_IMPORTS if len(name.split(".")) > 2})
    probe = ("import sys, importlib\n"
             f"for name in {list(CORE)!r}: importlib.import_module('vdtutorial.' + name)\n"
             f"allowed = {still!r}\n"
             "loaded = sorted({m.split('.')[1] for m in sys.modules if m.startswith('vdtutorial.') and m.count('.') >= 2}"
             " - {'envs'} - set(allowed))\n"
             "print(loaded)\n")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env={**os.environ},
                         cwd=PACKAGE.parent)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]", f"importing the core loaded the subpackages {run.stdout.strip()}"


def test_the_runner_rounds_the_columns_trpo_calls_timing():
    """The grid runner may not import TRPO, so it names the timing columns itself: the two lists must agree."""
    from vdtutorial.runner import rows
    from vdtutorial.trpo import TIMING_COLUMNS

    assert rows.TIMING_COLUMNS == TIMING_COLUMNS


#: What a docstring or comment of the core must not hold: measurements, their dates and the issues behind them
#: belong in docs/ (results, differences), which the docstrings link. A citation's year ("Schulman et al., 2015")
#: is a reference, not a date.
HISTORY = re.compile(r"[Mm]easured|\b[Ii]ssues? \d+|\b(?:January|February|March|April|May|June|July|August|September|"
                     r"October|November|December) \d{4}\b|\b\d{4}-\d{2}-\d{2}\b")


def _docs_and_comments(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every docstring and comment of ``path``."""
    source = path.read_text()
    found = [(node.body[0].lineno, ast.get_docstring(node, clean=False))
             for node in ast.walk(ast.parse(source)) if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
             and ast.get_docstring(node, clean=False)]
    found += [(token.start[0], token.string) for token in tokenize.generate_tokens(io.StringIO(source).readline)
              if token.type == tokenize.COMMENT]
    return found


def test_no_docstring_or_comment_in_the_core_names_an_issue_a_date_or_a_measurement():
    offending = [f"{path.relative_to(PACKAGE)}:{line}: {HISTORY.search(text).group(0)!r}"
                 for path in _core_files() for line, text in _docs_and_comments(path) if HISTORY.search(text)]
    assert not offending


#: The core's budget: the method in at most 2,600 lines, no module over 450.
CORE_LINES_MAX, MODULE_LINES_MAX = 2600, 450


def test_the_core_stays_small():
    lines = {str(path.relative_to(PACKAGE)): len(path.read_text().splitlines()) for path in _core_files()}
    assert max(lines.values()) <= MODULE_LINES_MAX, {k: v for k, v in lines.items() if v > MODULE_LINES_MAX}
    assert sum(lines.values()) <= CORE_LINES_MAX, f"the core grew to {sum(lines.values())} lines (budget {CORE_LINES_MAX})"
    assert len((PACKAGE / "__main__.py").read_text().splitlines()) <= 40
