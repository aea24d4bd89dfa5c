"""The library's core is the paper's method and nothing else: the modules directly in ``vdtutorial/`` (with
``envs/``) are the ones a learner reads beside the chapters, and they import only each other. The speed-ups,
the experiments, the grid runner, the course and the command line sit in subpackages that may import the
core, never the other way round.

Two lists record what has not moved yet: they may only shrink. A module that leaves the top level, or an
import that is cut, must be struck from its list (the tests say so), so the boundary never slips back."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import vdtutorial

PACKAGE = Path(vdtutorial.__file__).parent
#: The method, in the order the chapters teach it.
CORE = (
    "settings",
    "envs",
    "expert",
    "demos",
    "vd",
    "policy",
    "methods",
    "dropconnect",  # the layers of the table's binary-dropout entry, a method compared with VD as L2 is
    "pretrain",
    "trust_region",
    "baselines",
    "rollout",
    "trpo",
)
#: Top-level modules that are not the method and still wait for their subpackage.
NOT_YET_MOVED: set[str] = set()
#: Imports from a core module to outside the core that are still to be cut: (module, what it imports).
KNOWN_IMPORTS: set[tuple[str, str]] = set()


def _top_level() -> set[str]:
    return {p.stem for p in PACKAGE.glob("*.py") if p.stem not in ("__init__", "__main__")} | {"envs"}


def _core_files() -> list[Path]:
    return sorted(
        p for name in CORE for p in ([PACKAGE / f"{name}.py"] if name != "envs" else (PACKAGE / "envs").glob("*.py"))
    )


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
    assert top - set(CORE) <= NOT_YET_MOVED, (
        f"not the method, at the top level: {sorted(top - set(CORE) - NOT_YET_MOVED)}"
    )
    moved = NOT_YET_MOVED - top
    assert not moved, f"{sorted(moved)} left the top level: strike them from NOT_YET_MOVED"


def test_a_core_module_imports_only_the_core():
    crossing = {
        (path.stem if path.parent == PACKAGE else f"envs.{path.stem}", name)
        for path in _core_files()
        for name in _imports(path)
        if not _in_core(name)
    }
    assert crossing <= KNOWN_IMPORTS, f"the core imports from outside it: {sorted(crossing - KNOWN_IMPORTS)}"
    assert not KNOWN_IMPORTS - crossing, f"cut, so strike them from KNOWN_IMPORTS: {sorted(KNOWN_IMPORTS - crossing)}"


def test_the_core_runs_without_the_course_the_runner_or_the_experiments():
    """Not just the source text: a fresh interpreter that imports every core module loads no subpackage
    (the known imports aside, which are still listed above)."""
    still = sorted({name.split(".")[1] for _, name in KNOWN_IMPORTS if len(name.split(".")) > 2})
    probe = (
        "import sys, importlib\n"
        f"for name in {list(CORE)!r}: importlib.import_module('vdtutorial.' + name)\n"
        f"allowed = {still!r}\n"
        "loaded = sorted({m.split('.')[1] for m in sys.modules if m.startswith('vdtutorial.') and m.count('.') >= 2}"
        " - {'envs'} - set(allowed))\n"
        "print(loaded)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env={**os.environ}, cwd=PACKAGE.parent
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]", f"importing the core loaded the subpackages {run.stdout.strip()}"
