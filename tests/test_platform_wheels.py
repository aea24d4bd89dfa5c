"""Which platforms pip can serve: the package's dependencies (with the lab extra, what a learner installs) are
resolved for macOS, Windows and Linux aarch64 from wheels only, without installing anything (uv's
``pip compile --python-platform``), and the packages that have no wheel there are named. The README's route
for each platform must name the same packages: that is why its route is conda-forge.

These tests ask PyPI: they skip when it cannot be reached, unless VDTUTORIAL_NETWORK_TESTS=1 (CI) makes that
a failure."""

import os
import re
import shutil
import subprocess
import tomllib
import urllib.request
from functools import cache
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parent.parent
#: uv's name of each platform -> the README's name of its row, and the packages expected without a wheel.
PLATFORMS = {
    "aarch64-apple-darwin": ("macOS arm64", {"pybullet"}),
    "x86_64-apple-darwin": ("macOS x86_64", {"pybullet", "torch"}),
    "x86_64-pc-windows-msvc": ("Windows", {"pybullet"}),
    "aarch64-unknown-linux-gnu": ("Linux aarch64", {"pybullet"}),
}


@cache
def _pypi_reachable() -> bool:
    try:
        urllib.request.urlopen("https://pypi.org/simple/pip/", timeout=10).close()
        return True
    except OSError:
        return False


@pytest.fixture(autouse=True)
def _needs_pypi_and_uv():
    required = os.environ.get("VDTUTORIAL_NETWORK_TESTS") == "1"
    for missing, why in (
        (shutil.which("uv") is None, "uv is not installed (pip install uv)"),
        (not _pypi_reachable(), "PyPI cannot be reached"),
    ):
        if missing:
            if required:
                pytest.fail(why)
            pytest.skip(why)


def _learner_requirements() -> list[str]:
    """The dependencies and the lab extra, each without its environment marker: what would have to install."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    texts = project["dependencies"] + project["optional-dependencies"]["lab"]
    return [str(Requirement(text)).split(";")[0].strip() for text in texts]


def without_wheels(requirements: list[str], platform: str, python: str = "3.13") -> set[str]:
    """The requirements that have no wheel for ``platform``: resolve from wheels only, and take out each
    package the resolver names as having none, until the rest resolves."""
    missing, left = set(), list(requirements)
    while True:
        run = subprocess.run(
            [
                "uv",
                "pip",
                "compile",
                "-",
                "--python-platform",
                platform,
                "--python-version",
                python,
                "--only-binary",
                ":all:",
                "--no-header",
                "--quiet",
            ],
            input="\n".join(left),
            capture_output=True,
            text=True,
            timeout=300,
        )
        if run.returncode == 0:
            return missing
        named = re.search(r"Because (?:all versions of |only )?([A-Za-z0-9_.\-]+)", run.stderr)
        assert named, run.stderr
        name = named[1].lower()
        assert name not in missing and any(Requirement(r).name.lower() == name for r in left), (
            f"{name} stops the resolution but is not one of the requirements:\n{run.stderr}"
        )
        missing.add(name)
        left = [r for r in left if Requirement(r).name.lower() != name]


@pytest.mark.parametrize("platform", PLATFORMS)
def test_the_packages_without_a_wheel_are_the_ones_the_readme_names(platform):
    row_name, expected = PLATFORMS[platform]
    assert without_wheels(_learner_requirements(), platform) == expected
    readme = (ROOT / "README.md").read_text()
    row = next((line for line in readme.splitlines() if line.startswith(f"| {row_name} |")), None)
    assert row is not None, f"the README's route table has no row for {row_name}"
    for name in expected:
        assert f"no {name} wheel" in row, f"the README's {row_name} row does not say that {name} has no wheel"


def test_pip_never_builds_pybullet_where_it_has_no_wheel():
    """pyproject.toml's marker keeps pybullet out of pip's hands on macOS, Windows and Linux aarch64, so a
    learner there is never handed an unasked source build; Linux x86_64 (Colab included) requires it."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pybullet = next(Requirement(t) for t in project["dependencies"] if t.startswith("pybullet"))
    for system, machine in (("darwin", "arm64"), ("darwin", "x86_64"), ("win32", "AMD64"), ("linux", "aarch64")):
        assert not pybullet.marker.evaluate({"sys_platform": system, "platform_machine": machine})
    assert pybullet.marker.evaluate({"sys_platform": "linux", "platform_machine": "x86_64"})
