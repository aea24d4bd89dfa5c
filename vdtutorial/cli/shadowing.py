"""A folder named ``vdtutorial`` that Python takes for the package: found and stepped around before a command runs.

After ``pip install -e .`` the package is found by the editable install's finder, which Python asks only after
searching its path, and that search starts in the current folder. Run from the folder that holds a clone named
``vdtutorial`` (as ``git clone`` names it), the clone's root, which has no ``__init__.py``, is imported as an empty
namespace package; submodules still load through the finder, so a command would start and fail later, on whatever
it reads from the package itself (its version, its registered environments).

Not taught in a chapter: the command line's plumbing (chapter 00 shows the commands, vdtutorial/cli/).
"""

from __future__ import annotations

import os
import sys

import vdtutorial


def shadowing_folder() -> str | None:
    """The folder Python took for the package, or None when it found the package itself."""
    if getattr(vdtutorial, "__file__", None):
        return None
    return next(iter(vdtutorial.__path__), "vdtutorial")


def step_around_a_shadowing_folder() -> None:
    """Nothing when the package is the package. Otherwise start the command again without the current folder on
    Python's path (``-P``), where the package is found; if a folder shadows it from elsewhere on the path
    (``PYTHONPATH``), say so in one line and exit with code 2 before anything is written."""
    folder = shadowing_folder()
    if folder is None:
        return
    if not sys.flags.safe_path and os.path.abspath(folder) == os.path.abspath("vdtutorial"):
        sys.stdout.flush()
        os.execv(sys.executable, [sys.executable, "-P", "-m", "vdtutorial", *sys.argv[1:]])
    print(
        f"error: the folder {os.path.abspath(folder)} (a clone of vdtutorial?) hides the installed package from "
        "Python: run the command from another folder (cd into the clone, or cd ~), or take that folder's parent "
        "off PYTHONPATH",
        file=sys.stderr,
    )
    sys.exit(2)
