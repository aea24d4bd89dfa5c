"""pybullet, imported without its build-time banner.

pybullet's C extension writes ``pybullet build time: ...`` to the process's standard error on its first import. That
line would otherwise open every command (``--help`` included), every worker process and every notebook that imports
the package, so the first import happens here with file descriptor 2 pointed at ``/dev/null`` during the import
only: later warnings and errors are untouched. Importing pybullet anywhere later is free: Python reuses the module.

Taught in chapter 01.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import sys
import warnings


def _import_quietly():
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    if importlib.util.find_spec("pybullet") is None:  # vdtutorial/__init__.py adds how to get it on this machine
        raise ModuleNotFoundError("pybullet is not installed", name="pybullet")
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no standard error at all: nothing to protect
        import pybullet

        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pybullet = _import_quietly()


@functools.cache
def warn_if_images_are_slow() -> None:
    """Warn once per process when this pybullet has no numpy support: camera images then come back as
    Python sequences, which cost time on every image (a source build made in pip's isolated environment).
    Chapter 00's install check (:mod:`vdtutorial.course.install_check`) prints the command that rebuilds it."""
    if not pybullet.isNumpyEnabled():
        warnings.warn(
            "pybullet was built without numpy support: camera images come back slower (docs/install.md). "
            "Chapter 00's install check prints the command that rebuilds it.",
            stacklevel=3,
        )
