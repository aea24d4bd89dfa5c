"""Quick mode and the folders are read when a run starts: ``use_quick`` reaches every budget, whatever was imported
before, in the same process and in a running Jupyter kernel."""

import ast
import importlib
import json
import os
import pkgutil
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import pytest

import vdtutorial
from vdtutorial import settings
from vdtutorial.experiments import paths

PACKAGE_DIR = Path(vdtutorial.__file__).parent
#: The settings that are read when called: a call at import would freeze the value of that moment.
READ_WHEN_CALLED = {"budget", "is_quick", "data_dir", "runs_dir", "project_dir", "shipped_dir"}


def next_run_budgets() -> dict:
    """Every budget the next run would get, made now: configs, RL steps, seeds, expert episodes, smoothing."""
    from vdtutorial.experiments import (
        RunSpec,
        default_expert_episodes,
        default_seeds,
        default_total_steps,
        smooth_window,
    )
    from vdtutorial.experiments.figures import figure_specs
    from vdtutorial.experiments.checkpoints import default_config
    from vdtutorial.pretrain import PretrainConfig

    specs = figure_specs("fig4")
    return {
        "PretrainConfig()": asdict(PretrainConfig()),
        "default_config": {
            f"{reg} {obs}": asdict(default_config(reg, obs)) for reg in ("vd", "l2") for obs in ("state", "rgbd")
        },
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
    """Give the session its mode back (the variable is the mode) after a test switches it."""
    monkeypatch.setenv(settings.QUICK_ENV, os.environ.get(settings.QUICK_ENV, "0"))


def test_use_quick_after_importing_everything_sets_the_next_runs_budgets(restore_mode):
    for module in pkgutil.walk_packages(vdtutorial.__path__, "vdtutorial."):
        importlib.import_module(module.name)
    expected = {quick: _budgets_of_fresh_interpreter(quick) for quick in (True, False)}
    changed = [key for key in expected[True] if expected[True][key] != expected[False][key]]
    assert changed == list(expected[True]), "every budget listed differs between the modes"
    now = settings.is_quick()
    for quick in (not now, now, not now):  # both directions
        assert settings.use_quick(quick) is quick and settings.is_quick() is quick
        assert os.environ[settings.QUICK_ENV] == ("1" if quick else "0")  # worker processes follow
        assert json.loads(json.dumps(next_run_budgets())) == expected[quick]


def test_use_quick_none_keeps_the_mode(restore_mode):
    for quick in (True, False):
        settings.use_quick(quick)
        assert settings.use_quick(None) is quick and settings.is_quick() is quick


def budgets_sized_at_import(source: str) -> list[str]:
    """Where ``source`` calls ``budget(...)``, ``is_quick()``, ``data_dir()`` or ``runs_dir()`` outside the body of a
    function or lambda, i.e. at import: module and class statements, default arguments and decorators."""
    found = []

    def visit(node, at_import: bool):
        if at_import and isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name in READ_WHEN_CALLED:
                found.append(f"line {node.lineno}: {name}() at import")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            body = node.body if isinstance(node.body, list) else [node.body]
            outside = [
                *getattr(node, "decorator_list", []),
                *node.args.defaults,
                *[d for d in node.args.kw_defaults if d is not None],
            ]
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
    sized = (
        "from vdtutorial.settings import budget, data_dir\n"
        "STEPS = budget(300, 2)\n"
        "def f(n=settings.budget(5, 1), root=data_dir()):\n    return n\n"
        "@dataclass\nclass C:\n    epochs: int = budget(150, 4)\n"
    )
    assert len(budgets_sized_at_import(sized)) == 4
    at_call = (
        "def f(n=None):\n    return budget(5, 1) if n is None else n\n"
        "class C:\n    epochs: list = field(default_factory=lambda: [budget(1, 2)])\n"
        "    def __post_init__(self):\n        self.n = budget(3, 4)\n"
    )
    assert budgets_sized_at_import(at_call) == []


@pytest.mark.parametrize("path", sorted(PACKAGE_DIR.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_no_module_sizes_a_budget_at_import(path):
    assert budgets_sized_at_import(path.read_text()) == []


def test_the_settings_module_holds_constants_only():
    """The mode and the folders are functions: a value stored at import would be the one a learner's switch misses."""
    stored = {
        name
        for name, value in vars(settings).items()
        if not name.startswith("__") and not callable(value) and not isinstance(value, type(os))
    }
    assert stored == {"QUICK_ENV", "DATA_ENV", "BOOK_RECORD", "_PACKAGE", "INSTALLED_COPY", "annotations"}


def test_the_folders_follow_the_working_directory_and_the_variables(tmp_path, monkeypatch):
    monkeypatch.delenv(settings.DATA_ENV, raising=False)
    monkeypatch.delenv(paths.RUNS_ENV, raising=False)
    shipped = settings.data_dir()
    (tmp_path / "book" / "notebooks").mkdir(parents=True)
    (tmp_path / "book" / settings.BOOK_RECORD).write_text("{}")
    monkeypatch.chdir(tmp_path / "book" / "notebooks")  # a chapter run from a folder written by `notebooks DEST`
    assert (settings.data_dir(), paths.runs_dir()) == (tmp_path / "book" / "data", tmp_path / "book" / "runs")
    monkeypatch.setenv(settings.DATA_ENV, str(tmp_path / "elsewhere"))
    monkeypatch.setenv(paths.RUNS_ENV, str(tmp_path / "out"))
    assert (settings.data_dir(), paths.runs_dir()) == (tmp_path / "elsewhere", tmp_path / "out")
    monkeypatch.delenv(settings.DATA_ENV)
    monkeypatch.chdir(tmp_path)
    assert settings.data_dir() == shipped


def _run_in(client, code: str) -> str:
    """Execute ``code`` in the kernel behind ``client``; return what it printed (raise on an error)."""
    printed = []
    reply = client.execute_interactive(code, timeout=120, output_hook=lambda msg: printed.append(msg["content"]))
    if reply["content"]["status"] != "ok":
        raise AssertionError(f"{code!r} failed in the kernel: {reply['content'].get('evalue')}")
    return "".join(content.get("text", "") for content in printed)


def test_a_running_kernel_switches_quick_mode_without_a_restart():
    """What a learner does: start a chapter in one mode, change its first cell, run the chapter's cells again."""
    from jupyter_client.manager import start_new_kernel

    chapter = json.loads((settings.shipped_dir() / "notebooks" / "00_start_here.ipynb").read_text())
    mode_cell = next(
        "".join(c["source"])
        for c in chapter["cells"]
        if c["cell_type"] == "code" and "example: budget(200, 20)" in "".join(c["source"])
    )
    started = not settings.is_quick()
    manager, client = start_new_kernel(
        kernel_name="python3",
        env={**os.environ, settings.QUICK_ENV: str(int(started))},
        cwd=str(settings.shipped_dir() / "notebooks"),
    )
    try:
        _run_in(
            client, f"import vdtutorial.experiments, runpy\nbudgets = runpy.run_path({__file__!r})['next_run_budgets']"
        )
        for quick in (started, not started, started):
            _run_in(client, f"from vdtutorial.settings import use_quick\nuse_quick({quick})")
            printed = _run_in(client, mode_cell)
            assert ("quick mode: ON" in printed) is quick and f"budget(200, 20) -> {20 if quick else 200}" in printed
            budgets = _run_in(client, "import json; print(json.dumps(budgets()))")
            assert json.loads(budgets) == _budgets_of_fresh_interpreter(quick)
    finally:
        client.stop_channels()
        manager.shutdown_kernel(now=True)


@pytest.mark.parametrize("path", sorted((settings.shipped_dir() / "notebooks").glob("*.ipynb")), ids=lambda p: p.stem)
def test_no_chapter_asks_for_a_kernel_restart(path):
    text = " ".join("".join(cell["source"]) for cell in json.loads(path.read_text())["cells"])
    assert "restart the kernel" not in " ".join(text.split())
