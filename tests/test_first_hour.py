"""What a new user meets first: ``--help`` answers without loading torch, and the commands work when run from the
folder that holds a clone named ``vdtutorial`` (as ``git clone`` names it)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import vdtutorial
from vdtutorial.settings import BOOK_RECORD

#: The folder that holds the package this test imports (a clone's root, or site-packages for a wheel).
PACKAGE_PARENT = Path(vdtutorial.__file__).resolve().parent.parent


def test_help_imports_no_torch():
    probe = (
        "import runpy, sys\n"
        "sys.argv = ['vdtutorial', '--help']\n"
        "try:\n"
        "    runpy.run_module('vdtutorial', run_name='__main__')\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = sorted({'torch', 'matplotlib', 'scipy', 'ray'} & {m.split('.')[0] for m in sys.modules})\n"
        "print('HEAVY', ','.join(heavy))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "usage: python -m vdtutorial" in result.stdout
    assert result.stdout.strip().splitlines()[-1] == "HEAVY", result.stdout[-500:]


#: A meta path finder that resolves ``vdtutorial`` to this test's package only after Python's own path search, as
#: setuptools' editable install (``pip install -e .``) does: a folder named ``vdtutorial`` in the current directory
#: is then found first, as a namespace package. It stands in for any editable install of the package already in
#: this environment (which may point at another checkout).
EDITABLE_LIKE = f"""
import importlib.machinery, sys

sys.meta_path[:] = [f for f in sys.meta_path if "vdtutorial" not in getattr(f, "__module__", "")]
sys.path[:] = [p for p in sys.path if "__editable__.vdtutorial" not in p]

class _Editable:
    @staticmethod
    def find_spec(name, path=None, target=None):
        where = {{"": {str(PACKAGE_PARENT)!r}, "vdtutorial": {str(PACKAGE_PARENT / "vdtutorial")!r}}}
        if name == "vdtutorial" or name.rpartition(".")[0] == "vdtutorial":
            return importlib.machinery.PathFinder.find_spec(name, [where[name.rpartition(".")[0]]])
        return None

sys.meta_path.insert(sys.meta_path.index(importlib.machinery.PathFinder) + 1, _Editable)
"""


def _from_the_folder_of_a_clone(tmp_path, argv, pythonpath=()):
    """Run ``python -m vdtutorial ARGV`` from a folder holding a directory ``vdtutorial`` (a clone's root: no
    ``__init__.py``), with the package found only through an editable-style finder."""
    home = tmp_path / "home"
    (home / "vdtutorial" / "docs").mkdir(parents=True)
    (home / "vdtutorial" / "README.md").write_text("a clone\n")
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(EDITABLE_LIKE)
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env.update(PYTHONPATH=os.pathsep.join([*map(str, pythonpath), str(site)]), VDTUTORIAL_QUICK="1")
    return subprocess.run(
        [sys.executable, "-m", "vdtutorial", *argv], cwd=home, env=env, capture_output=True, text=True
    )


@pytest.mark.pipeline
def test_notebooks_from_the_folder_that_holds_a_clone(tmp_path):
    dest = tmp_path / "mybook"
    result = _from_the_folder_of_a_clone(tmp_path, ["notebooks", str(dest)])
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert json.loads((dest / BOOK_RECORD).read_text())["vdtutorial"] == vdtutorial.__version__
    assert (dest / "notebooks" / "00_start_here.ipynb").is_file()


@pytest.mark.pipeline
def test_a_clone_on_pythonpath_gives_one_error_line_and_writes_nothing(tmp_path):
    if PACKAGE_PARENT.name in ("site-packages", "dist-packages"):
        pytest.skip("installed from a wheel, the package is found on the path before any folder that could hide it")
    dest = tmp_path / "mybook"
    result = _from_the_folder_of_a_clone(tmp_path, ["notebooks", str(dest)], pythonpath=[tmp_path / "home"])
    assert result.returncode == 2, result.stderr[-2000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert str(tmp_path / "home" / "vdtutorial") in lines[0] and "cd " in lines[0]
    assert not dest.exists()
