"""Quick mode is decided when a run starts: ``use_quick`` reaches every budget, whatever was imported before."""
import ast
import importlib
import json
import os
import pkgutil
import runpy
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import pytest

import vdtutorial
from vdtutorial import settings

PACKAGE_DIR = Path(vdtutorial.__file__).parent


def next_run_budgets() -> dict:
    """Every budget the next run would get, made now: configs, RL steps, seeds, expert episodes, smoothing."""
    from vdtutorial.experiments import (RunSpec, default_expert_episodes, default_seeds, default_total_steps,
                                        smooth_window)
    from vdtutorial.experiments.figures import figure_specs
    from vdtutorial.pretrain import PretrainConfig, default_config

    specs = figure_specs("fig4")
    return {
        "PretrainConfig()": asdict(PretrainConfig()),
        "default_config": {f"{reg} {obs}": asdict(default_config(reg, obs)) for reg in ("vd", "l2")
                           for obs in ("state", "rgbd")},
        "RunSpec total_steps": RunSpec("vd").total_steps,
        "default_total_steps": default_total_steps(),
        "fig4 seeds": sorted({spec.seed for spec in specs}),
        "fig4 total_steps": sorted({spec.total_steps for spec in specs}),
        "default_seeds": list(default_seeds()),
        "default_expert_episodes": default_expert_episodes(),
        "smooth_window": smooth_window(),
    }


def _budgets_of_fresh_interpreter(quick: bool) -> dict:
    """What :func:`next_run_budgets` gives in a new interpreter whose mode is set by the environment before
    anything is imported (the way CI and the command line set it)."""
    code = f"import json, runpy; print(json.dumps(runpy.run_path({__file__!r})['next_run_budgets']()))"
    env = {**os.environ, settings.QUICK_ENV: "1" if quick else "0"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.splitlines()[-1])


@pytest.fixture
def restore_mode(monkeypatch):
    """Give the session its mode back (the flag and the variable) after a test switches it."""
    monkeypatch.setattr(settings, "QUICK", settings.QUICK)
    monkeypatch.setenv(settings.QUICK_ENV, os.environ.get(settings.QUICK_ENV, "0"))


def test_use_quick_after_importing_everything_sets_the_next_runs_budgets(restore_mode):
    for module in pkgutil.walk_packages(vdtutorial.__path__, "vdtutorial."):
        importlib.import_module(module.name)
    expected = {quick: _budgets_of_fresh_interpreter(quick) for quick in (True, False)}
    changed = [key for key in expected[True] if expected[True][key] != expected[False][key]]
    assert changed == list(expected[True]), "every budget listed differs between the modes"
    for quick in (not settings.QUICK, settings.QUICK, not settings.QUICK):  # both directions
        assert settings.use_quick(quick) is quick and settings.is_quick() is quick
        assert os.environ[settings.QUICK_ENV] == ("1" if quick else "0")  # worker processes follow
        assert json.loads(json.dumps(next_run_budgets())) == expected[quick]


def test_use_quick_none_keeps_the_mode(restore_mode):
    for quick in (True, False):
        settings.use_quick(quick)
        assert settings.use_quick(None) is quick and settings.is_quick() is quick


def budgets_sized_at_import(source: str) -> list[str]:
    """Where ``source`` calls ``budget(...)`` or imports the ``QUICK`` flag by name, outside the body of a
    function or lambda, i.e. at import: module and class statements, default arguments and decorators."""
    found = []

    def visit(node, at_import: bool):
        if at_import and isinstance(node, ast.Call):
            func = node.func
            if (func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)) == "budget":
                found.append(f"line {node.lineno}: budget() at import")
        if isinstance(node, ast.ImportFrom) and any(alias.name == "QUICK" for alias in node.names):
            found.append(f"line {node.lineno}: imports QUICK (a copy of the flag as it was then)")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            body = node.body if isinstance(node.body, list) else [node.body]
            outside = [*getattr(node, "decorator_list", []), *node.args.defaults,
                       *[d for d in node.args.kw_defaults if d is not None]]
            for child in outside:
                visit(child, at_import)
            for child in body:
                visit(child, False)
            return
        for child in ast.iter_child_nodes(node):
            visit(child, at_import)

    visit(ast.parse(source), True)
    return found


def test_the_check_finds_budgets_sized_at_import():
    sized = ("from vdtutorial.settings import QUICK, budget\n"
             "STEPS = budget(300, 2)\n"
             "def f(n=settings.budget(5, 1)):\n    return n\n"
             "@dataclass\nclass C:\n    epochs: int = budget(150, 4)\n")
    assert len(budgets_sized_at_import(sized)) == 4
    at_call = ("def f(n=None):\n    return budget(5, 1) if n is None else n\n"
               "class C:\n    epochs: list = field(default_factory=lambda: [budget(1, 2)])\n"
               "    def __post_init__(self):\n        self.n = budget(3, 4)\n")
    assert budgets_sized_at_import(at_call) == []


@pytest.mark.parametrize("path", sorted(PACKAGE_DIR.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_no_module_sizes_a_budget_at_import(path):
    assert budgets_sized_at_import(path.read_text()) == []
