"""The chapters' first code cell, which makes a chapter opened by itself in Google Colab run: on Colab it installs
the package into the runtime (adding packages, never replacing Colab's own), builds pybullet with numpy support or
reuses a wheel kept from an earlier runtime, writes the chapters and their data to a folder and moves there; anywhere
else it does nothing.

One source: :data:`CELL` is the cell's code. The README's Colab cell and every notebook's cell ``colab-setup`` are
its text with the project's address filled in (tests/test_colab_cell.py checks both), and CI's Colab leg runs it
from the chapters (``.ci/run``). ``python -m vdtutorial.course.colab`` writes it into the notebooks of a checkout,
with an "Open in Colab" link in each title cell when the project's public address is set (``[project.urls]
Repository`` in pyproject.toml, the one place it is kept); without one, no link.

The cell is plain Python, not IPython's ``!pip``, so that one text serves a pasted cell and a chapter. Three
environment variables stand in for Colab's places where Colab is not at hand (CI): ``VDTUTORIAL_SOURCE`` (what
pip installs), ``VDTUTORIAL_BOOK`` (the folder, ``/content/vdtutorial`` on Colab) and ``VDTUTORIAL_WHEELS`` (the
folder that keeps the built pybullet wheel; on Colab ``vdtutorial-wheels`` in Google Drive when it is mounted).

Not taught in a chapter: how the chapters reach Colab (README: "Google Colab").
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import nbformat

#: The id of the cell in every notebook.
CELL_ID = "colab-setup"
#: The line of :data:`CELL` that holds what pip installs, filled by :func:`cell_source`.
SOURCE_LINE = 'SOURCE = ""  # what pip installs: the project\'s "git+https://..." address, or a wheel you uploaded'

CELL = f"""\
#@title On Google Colab: install vdtutorial and its data (2 min; building pybullet: 5 min, once). Elsewhere: nothing
{SOURCE_LINE}
import glob, os, subprocess, sys, time
BOOK, DRIVE = os.environ.get("VDTUTORIAL_BOOK", "/content/vdtutorial"), "/content/drive/MyDrive"
if "google.colab" in sys.modules and not os.path.isfile(f"{{BOOK}}/vdtutorial-book.json"):
    start, keep = time.time(), "/tmp/colab-keep.txt"  # Colab's versions: pip may add packages, not replace them
    SOURCE = os.environ.get("VDTUTORIAL_SOURCE") or SOURCE or max(glob.glob("/content/vdtutorial-*.whl"), default="")
    if not SOURCE:
        raise RuntimeError("set SOURCE to the project's git+https:// address, or upload a vdtutorial wheel to /content")
    print(f"Installing vdtutorial, then writing its chapters and data to {{BOOK}} (1-2 minutes)")
    pip = lambda *args, **run: subprocess.run([sys.executable, "-m", "pip", *args, "-q", "-c", keep], **run)
    subprocess.run(f"{{sys.executable}} -m pip list --format=freeze > {{keep}}", shell=True, check=True)
    pip("install", "numpy>=2.1", "setuptools", "wheel", check=True)
    wheels = os.environ.get("VDTUTORIAL_WHEELS") or (f"{{DRIVE}}/vdtutorial-wheels" if os.path.isdir(DRIVE) else "")
    kept = ["--no-index", "--find-links", wheels or "/tmp/vdtutorial-wheels", "pybullet>=3.2.5"]
    kept_wheel = wheels and glob.glob(f"{{wheels}}/pybullet-*.whl")  # a wheel of an earlier runtime, if any
    if kept_wheel and pip("install", *kept, capture_output=True).returncode == 0:
        print(f"pybullet: installed the wheel kept in {{wheels}} (no build)")
    else:
        print("pybullet: building it with numpy support, about 5 minutes on Colab's 2 cores; " + (
            f"its wheel is kept in {{wheels}} for your next runtime" if wheels else
            "mount Google Drive before running this cell to keep its wheel for your next runtime"), flush=True)
        pip("wheel", "--no-deps", "--no-build-isolation", "--no-cache-dir", "-w", kept[2], kept[3], check=True)
        pip("install", *kept, check=True)
    pip("install", SOURCE, check=True)
    subprocess.run([sys.executable, "-m", "vdtutorial", "notebooks", BOOK], stdout=subprocess.DEVNULL, check=True)
    print(f"ready in {{time.time() - start:.0f}} s")
if "google.colab" in sys.modules:
    os.chdir(BOOK)  # the chapters read data/ and write runs/ there
"""


def public_address(root: Path) -> str | None:
    """The project's public repository address (``[project.urls] Repository`` in ``root/pyproject.toml``), if set."""
    urls = tomllib.loads((root / "pyproject.toml").read_text())["project"].get("urls", {})
    return urls.get("Repository")


def cell_source(address: str | None) -> str:
    """:data:`CELL` with ``SOURCE`` set to the project's ``git+`` address, or left empty without one."""
    if not address:
        return CELL
    filled = f'SOURCE = "git+{address}"  # what pip installs (or the path of a wheel you uploaded)'
    return CELL.replace(SOURCE_LINE, filled)


def colab_link(address: str, notebook: str) -> str:
    """The "Open in Colab" badge of a chapter of the GitHub repository at ``address`` (its default branch)."""
    path = re.sub(r"^https://github\.com/", "", address.rstrip("/"))
    return (
        f"[![Open in Colab](https://colab.research.google.com/assets/colab-badge.svg)]"
        f"(https://colab.research.google.com/github/{path}/blob/main/notebooks/{notebook})"
    )


def with_colab_cell(notebook, name: str, address: str | None):
    """``notebook`` with the cell :data:`CELL_ID` (added just before the first code cell, or brought up to date)
    and, in its title cell, the "Open in Colab" link when ``address`` is set (removed when it is not)."""
    cells = [cell for cell in notebook.cells if cell.get("id") != CELL_ID]
    first_code = next(k for k, cell in enumerate(cells) if cell.cell_type == "code")
    cell = nbformat.v4.new_code_cell(cell_source(address), id=CELL_ID)
    cell.metadata = {"cellView": "form"}  # Colab shows the title line and folds the code
    cells.insert(first_code, cell)
    title = cells[0]
    title.source = re.sub(r"\n\n\[!\[Open in Colab\]\([^)]*\)\]\([^)]*\)$", "", title.source)
    if address:
        title.source += "\n\n" + colab_link(address, name)
    notebook.cells = cells
    return notebook


def write_colab_cells(root: Path) -> list[Path]:
    """Bring the cell (and the links) of every notebook in ``root/notebooks`` up to date; returns the changed ones."""
    address, changed = public_address(root), []
    for path in sorted((root / "notebooks").glob("*.ipynb")):
        before = path.read_text()
        notebook = with_colab_cell(nbformat.reads(before, as_version=4), path.name, address)
        after = nbformat.writes(notebook) + "\n"
        if after != before:
            path.write_text(after)
            changed.append(path)
    return changed


if __name__ == "__main__":
    for written in write_colab_cells(Path.cwd()):
        print(f"wrote {written}")
