"""What this machine has, and how it got it: chapter 00's environment check, one line per item.

Each check returns ``(status, item, message)`` rows: ``ok``, ``note`` (worth knowing, nothing to do) or
``FIX`` (with the command that fixes it). Nothing raises, so a learner sees every problem at once.

pybullet is the piece that differs most between machines. Its last release (3.2.7) has prebuilt wheels
only for Linux x86_64 and CPython up to 3.11. So each platform has one route (:func:`platform_route`, the
README's table): pip on Linux x86_64 (compiling pybullet once on Python 3.12+), the README's cell on Colab,
and conda-forge's build on macOS, Windows and Linux aarch64. A source build made in pip's isolated build
environment has no numpy in it, so ``pybullet.isNumpyEnabled()`` is 0 and every camera image comes back as
Python lists, which costs time on every image (docs/install.md gives the measured cost).

Taught in chapter 00.
"""

from __future__ import annotations

import importlib
import importlib.util
import importlib.metadata as md
import platform
import sys
from pathlib import Path

#: The release the source-build commands name (the one the shipped results were made with).
PYBULLET_RELEASE = "3.2.7"
#: The commands that build pybullet with numpy support: numpy must be in the environment before the build,
#: and pip's cache must not hand back a wheel an earlier isolated build left there.
NUMPY_BUILD = (
    "pip install numpy setuptools wheel && pip install --force-reinstall --no-cache-dir "
    f"--no-build-isolation pybullet=={PYBULLET_RELEASE}"
)
#: What images without numpy support cost a learner (docs/install.md: the rgbd env at 128 px, one process,
#: with and without numpy inside pybullet, on the project's 2-core machine).
NO_NUMPY_COST = "the image environments step about 1.6x slower (docs/install.md)."
#: The conda-forge route (environment.yml), for the platforms where PyPI has no pybullet wheel: the package goes
#: in with --no-deps, so that pip never replaces a conda package.
CONDA_ROUTE = "conda env create -f environment.yml && conda activate vdtutorial && pip install --no-deps -e ."
#: Each platform's route, as the README's install table names the platform.
ROUTES = {
    "Linux x86_64": "pip (README: the two commands)",
    "Google Colab": "the README's Colab cell",
    "macOS arm64": f"conda-forge: `{CONDA_ROUTE}`",
    "macOS x86_64": f"conda-forge: `{CONDA_ROUTE}`",
    "Windows": f"conda-forge: `{CONDA_ROUTE}`",
    "Linux aarch64": f"conda-forge: `{CONDA_ROUTE}`",
}


def on_colab() -> bool:
    """Whether this kernel runs on Google Colab (its ``google.colab`` module is importable). Looking for it
    imports the ``google`` namespace package, which an environment without any Google package lacks."""
    try:
        return importlib.util.find_spec("google.colab") is not None
    except ModuleNotFoundError:
        return False


def pybullet_route(distribution=None) -> str:
    """How pybullet arrived: ``"conda"`` (a conda package), ``"wheel"`` (a prebuilt manylinux/macOS/Windows
    wheel from the package index) or ``"source"`` (built on this machine from the sdist), read from the
    installed distribution's metadata. ``distribution``: an ``importlib.metadata.Distribution`` (tests)."""
    dist = distribution or md.distribution("pybullet")
    if (dist.read_text("INSTALLER") or "").strip() == "conda" or _conda_record("pybullet"):
        return "conda"
    tags = [
        line.split(":", 1)[1].strip()
        for line in (dist.read_text("WHEEL") or "").splitlines()
        if line.startswith("Tag:")
    ]
    # an index's wheel carries a portable platform tag; a wheel pip builds here names the bare platform
    portable = ("manylinux", "musllinux", "macosx", "win")
    return "wheel" if any(tag.split("-")[-1].startswith(portable) for tag in tags) else "source"


def _conda_record(name: str) -> bool:
    return any((Path(sys.prefix) / "conda-meta").glob(f"{name}-[0-9]*.json"))


def platform_route() -> str:
    """This machine's row of :data:`ROUTES`: ``"Google Colab"``, ``"Linux x86_64"``, ``"macOS arm64"``, ..."""
    if on_colab():
        return "Google Colab"
    system, machine = platform.system(), platform.machine().lower()
    if system == "Darwin":
        return "macOS arm64" if machine == "arm64" else "macOS x86_64"
    if system == "Windows":
        return "Windows"
    return "Linux x86_64" if machine in ("x86_64", "amd64") else "Linux aarch64"


def missing_pybullet() -> str:
    """What to run when pybullet is missing, for this platform and Python (the package's import says it too)."""
    route = platform_route()
    if route == "Google Colab":
        return "run the README's Colab cell (it compiles pybullet with numpy support, about 5 minutes)"
    if route == "Linux x86_64" and sys.version_info[:2] <= (3, 11):
        return f"`pip install pybullet=={PYBULLET_RELEASE}` (a prebuilt wheel)"
    if route == "Linux x86_64":
        return (
            f"build it once (about 3-7 minutes on 2 cores; it needs g++ and the Python headers, e.g. "
            f"`sudo apt install g++ python3-dev`): `{NUMPY_BUILD}`"
        )
    return f"PyPI has no pybullet wheel for {route}: use conda-forge's build, `{CONDA_ROUTE}`"


def pybullet_checks() -> list[tuple[str, str, str]]:
    """pybullet's presence, its route (wheel, source build, conda) and its numpy support."""
    try:
        import pybullet
    except ImportError:
        return [("FIX", "pybullet", f"not installed: {missing_pybullet()}")]
    route = pybullet_route()
    described = {
        "wheel": "a prebuilt wheel",
        "source": "built from source on this machine",
        "conda": "a conda package",
    }[route]
    rows = [("ok", "pybullet", f"{md.version('pybullet')}, {described}")]
    if pybullet.isNumpyEnabled():
        rows.append(("ok", "pybullet numpy", "built with numpy support (fast camera images)"))
    else:
        if route == "conda" or platform_route() not in ("Linux x86_64", "Google Colab"):
            fix = "conda install -c conda-forge --force-reinstall pybullet"
        elif route == "source" or sys.version_info[:2] > (3, 11):
            fix = NUMPY_BUILD
        else:
            fix = "pip install --force-reinstall --no-cache-dir pybullet"
        rows.append(("FIX", "pybullet numpy", f"built WITHOUT numpy support: {NO_NUMPY_COST} Rebuild it: `{fix}`"))
    return rows


def package_checks(names=("numpy", "torch", "gymnasium", "meshcat", "matplotlib", "ipywidgets")) -> list[tuple]:
    """Each package installed and importable, with its version (pybullet: :func:`pybullet_checks`). In a conda
    environment a missing package comes from environment.yml, not from pip: pip would fetch it from PyPI beside
    conda's packages (and, asked for the package's dependencies, try to build pybullet from source)."""
    rows = []
    in_conda = (Path(sys.prefix) / "conda-meta").is_dir()
    for name in names:
        try:
            version = md.version(name)
            importlib.import_module(name)
        except md.PackageNotFoundError:
            source = (
                "`conda env update -f environment.yml` (in the clone) brings it in"
                if in_conda
                else "`pip install vdtutorial` (or `pip install -e .` in a clone) pulls it in"
            )
            rows.append(("FIX", name, f"not installed: {source}"))
            continue
        except Exception as exc:  # installed but broken
            rows.append(
                (
                    "FIX",
                    name,
                    f"installed ({version}) but `import {name}` fails: {exc!r}. Reinstall it: "
                    f"`pip install --force-reinstall {name}`",
                )
            )
            continue
        rows.append(("ok", name, version))
    return rows


def python_check() -> tuple[str, str, str]:
    """The Python version, and this platform's route."""
    version = platform.python_version()
    if sys.version_info[:2] < (3, 11):
        return ("FIX", "python", f"{version}: vdtutorial needs Python 3.11 or newer")
    return ("ok", "python", f"{version} ({sys.executable}); {platform_route()}: {ROUTES[platform_route()]}")


def front_end_checks() -> list[tuple[str, str, str]]:
    """What the notebook front end needs to draw widgets, and what torch will run on."""
    rows = []
    try:
        rows.append(("ok", "jupyterlab_widgets", md.version("jupyterlab_widgets")))
    except md.PackageNotFoundError:
        rows.append(
            (
                "note",
                "jupyterlab_widgets",
                "not found: sliders may show as plain text in JupyterLab. "
                "Fix with `pip install jupyterlab_widgets` (then restart JupyterLab)",
            )
        )
    try:
        import torch

        rows.append(
            (
                "ok",
                "torch threads",
                f"{torch.get_num_threads()} CPU threads; CUDA available: "
                f"{torch.cuda.is_available()} (not needed, everything here runs on the CPU)",
            )
        )
    except ImportError:
        pass  # reported by package_checks
    return rows


def environment_checks() -> list[tuple[str, str, str]]:
    """Every check of this module, in the order chapter 00 prints them."""
    rows = [python_check(), *package_checks(), *pybullet_checks(), *front_end_checks()]
    if on_colab():
        rows.append(("note", "colab", "running on Google Colab: chapter 00 turns on Colab's widget manager"))
    return rows
