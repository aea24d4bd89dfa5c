"""The chapters' first cell (vdtutorial/course/colab.py): one text in the README and every notebook, and what it does
with a Colab marker (install, build pybullet once and keep its wheel, reuse it on the next runtime) and without one
(nothing). pip is a stand-in here that records its calls; CI's Colab leg runs the cell with the real one."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

from vdtutorial.course.colab import CELL_ID, cell_source, public_address, with_colab_cell

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_the_readme_cell_is_the_chapters_first_cell():
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"<!-- colab-cell.*?-->\n```python\n(.*?)```", readme, re.S)[1]
    assert block == cell_source(public_address(ROOT))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_notebook_runs_the_cell_before_its_own_code(path):
    notebook = nbformat.read(path, as_version=4)
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert code[0].get("id") == CELL_ID and code[0].source == cell_source(public_address(ROOT))
    assert sum(cell.get("id") == CELL_ID for cell in notebook.cells) == 1
    assert code[0].execution_count is None and not code[0].outputs
    assert ("colab.research.google.com" in notebook.cells[0].source) == bool(public_address(ROOT))


def test_a_public_address_gives_the_link_and_the_source():
    notebook = nbformat.read(NOTEBOOKS[1], as_version=4)
    address = "https://github.com/someone/vdtutorial"
    linked = with_colab_cell(nbformat.from_dict(json.loads(json.dumps(notebook))), NOTEBOOKS[1].name, address)
    assert linked.cells[0].source.endswith(
        f"(https://colab.research.google.com/github/someone/vdtutorial/blob/main/notebooks/{NOTEBOOKS[1].name})"
    )
    cell = next(c for c in linked.cells if c.get("id") == CELL_ID)
    assert 'SOURCE = "git+https://github.com/someone/vdtutorial"' in cell.source
    unlinked = with_colab_cell(linked, NOTEBOOKS[1].name, None)
    assert unlinked.cells[0].source == notebook.cells[0].source
    assert [c.source for c in unlinked.cells] == [c.source for c in notebook.cells]


#: A stand-in for ``python -m pip``: records each call; ``wheel -w DIR`` writes a small fake pybullet wheel there;
#: ``install --no-index --find-links DIR`` succeeds only if DIR holds one; everything else succeeds.
FAKE_PIP = """
import json, os, pathlib, sys
args = sys.argv[1:]
with open(os.environ["FAKE_PIP_LOG"], "a") as log:
    log.write(json.dumps(args) + "\\n")
if args[0] == "list":
    print("numpy==2.3.0")
elif args[0] == "wheel":
    out = pathlib.Path(args[args.index("-w") + 1])
    out.mkdir(parents=True, exist_ok=True)
    (out / "pybullet-3.2.7-cp311-cp311-linux_x86_64.whl").write_bytes(b"a fake wheel")
elif args[0] == "install" and "--no-index" in args:
    sys.exit(0 if list(pathlib.Path(args[args.index("--find-links") + 1]).glob("pybullet-*.whl")) else 1)
"""


def _run_cell(tmp_path, on_colab: bool, wheels: Path | None):
    """Run the cell in a fresh interpreter (with Colab's marker module or without), with the stand-in pip; returns
    what it printed, the pip calls it made and the folder it ended in."""
    fake = tmp_path / "fake"
    (fake / "pip").mkdir(parents=True, exist_ok=True)
    (fake / "pip" / "__init__.py").write_text("")  # a regular package: found before the real pip
    (fake / "pip" / "__main__.py").write_text(FAKE_PIP)
    log = tmp_path / "pip.log"
    log.write_text("")
    marker = "import sys, types; sys.modules['google.colab'] = types.ModuleType('google.colab')\n" if on_colab else ""
    script = marker + cell_source(None) + "\nprint('CWD', os.getcwd())\n"
    env = {
        **os.environ,
        "FAKE_PIP_LOG": str(log),
        "VDTUTORIAL_SOURCE": "vdtutorial-0.1.0-py3-none-any.whl",
        "VDTUTORIAL_BOOK": str(tmp_path / "content" / "vdtutorial"),
        "PYTHONPATH": os.pathsep.join([str(fake), *filter(None, [os.environ.get("PYTHONPATH")])]),
    }
    env.pop("VDTUTORIAL_WHEELS", None)
    if wheels is not None:
        env["VDTUTORIAL_WHEELS"] = str(wheels)
    result = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    lines = result.stdout.splitlines()
    return lines[:-1], calls, lines[-1].removeprefix("CWD ")


@pytest.mark.pipeline
def test_on_colab_the_cell_installs_builds_once_and_reuses_the_kept_wheel(tmp_path):
    book, drive = tmp_path / "content" / "vdtutorial", tmp_path / "drive" / "vdtutorial-wheels"
    printed, calls, cwd = _run_cell(tmp_path, on_colab=True, wheels=drive)
    building = [line for line in printed if line.startswith("pybullet: building it with numpy support, about 5 min")]
    assert len(building) == 1 and f"its wheel is kept in {drive} for your next runtime" in building[0]
    # no kept wheel in the folder: no install from it is tried (a find-links of pip's own must not pass for one)
    assert [call[0] for call in calls] == ["list", "install", "wheel", "install", "install"]
    assert all(call[-2:] == ["-c", "/tmp/colab-keep.txt"] for call in calls[1:])  # Colab's versions held
    assert "vdtutorial-0.1.0-py3-none-any.whl" in calls[-1]
    assert list(drive.glob("pybullet-*.whl")) and (book / "vdtutorial-book.json").is_file() and cwd == str(book)

    again, calls, _ = _run_cell(tmp_path, on_colab=True, wheels=drive)  # the same runtime: installed already
    assert again == [] and calls == []

    for path in sorted(book.rglob("*"), reverse=True):  # a new runtime: the folder is gone, Drive keeps the wheel
        path.unlink() if path.is_file() else path.rmdir()
    printed, calls, cwd = _run_cell(tmp_path, on_colab=True, wheels=drive)
    assert f"pybullet: installed the wheel kept in {drive} (no build)" in printed
    assert "wheel" not in [call[0] for call in calls] and not any("building" in line for line in printed)
    assert cwd == str(book)


def test_elsewhere_the_cell_does_nothing(tmp_path):
    printed, calls, cwd = _run_cell(tmp_path, on_colab=False, wheels=None)
    assert printed == [] and calls == [] and cwd == str(tmp_path)
