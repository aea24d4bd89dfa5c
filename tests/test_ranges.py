"""The ranges of pyproject.toml and the environment files admit what learners have: Google Colab's published runtime,
the newest releases on PyPI, and what conda-forge builds for each of the five platforms; no upper bound that a
new release can cross but the reasoned caps. The reference files in tests/reference/ say where and when each
version was read."""

import csv
import re
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "tests" / "reference"
PLATFORMS = ("linux-64", "linux-aarch64", "osx-64", "osx-arm64", "win-64")
#: conda-forge's names for the packages PyPI knows by another name (as in test_packaging).
CONDA_NAMES = {"pytorch-cpu": "torch", "meshcat-python": "meshcat", "ray-default": "ray"}


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirements() -> list[Requirement]:
    """Every requirement of the package and its extras."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    texts = project["dependencies"] + [r for extra in project["optional-dependencies"].values() for r in extra]
    return [Requirement(text) for text in texts]


def _rows(name: str) -> list[dict]:
    lines = [line for line in (REFERENCE / name).read_text().splitlines() if line and not line.startswith("#")]
    return list(csv.DictReader(lines, delimiter="\t"))


def _colab() -> dict[str, str]:
    """Colab's freeze, name -> version (a wheel's URL read for its version, without the local tag)."""
    versions = {}
    for line in (REFERENCE / "colab-2026-08-19-pip-freeze.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        if " @ " in line:
            name, url = line.split(" @ ", 1)
            if m := re.search(r"/[^/]+-(\d[^-/]*)-[^/-]+-[^/-]+-[^/-]+\.whl", url.replace("%2B", "+")):
                versions[_canonical(name)] = m[1].split("+")[0]
        else:
            name, version = line.split("==")
            versions[_canonical(name)] = version.strip()
    return versions


def test_every_dependency_admits_colabs_version():
    """Installing the package on Colab replaces none of what Colab has (torch 2.11.0, ipywidgets 7.7.1...)."""
    colab = _colab()
    assert colab["torch"] == "2.11.0" and colab["ipywidgets"] == "7.7.1"  # the runtime the issue names
    checked = 0
    for requirement in _requirements():
        version = colab.get(_canonical(requirement.name))
        if version is not None and not requirement.name.startswith(("nbgrader", "jupyterlab")):
            assert requirement.specifier.contains(version), f"{requirement} refuses Colab's {version}"
            checked += 1
    assert checked >= 12


def test_no_dependency_of_the_package_pulls_in_a_front_end():
    """Colab's front end (notebook 6, its own jupyter-server) stays: JupyterLab is an extra, not a dependency."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = {_canonical(Requirement(text).name) for text in project["dependencies"]}
    assert not names & {"jupyterlab", "notebook", "ipykernel", "jupyter-server", "nbgrader"}
    assert any(Requirement(text).name == "jupyterlab" for text in project["optional-dependencies"]["lab"])


def test_every_dependency_admits_the_newest_release():
    """The newest releases recorded in tests/reference/pypi-newest.tsv (torch 2.15.0 among them) are admitted."""
    newest = {_canonical(row["package"]): row["newest"] for row in _rows("pypi-newest.tsv")}
    assert newest["torch"] == "2.15.0"
    for requirement in _requirements():
        assert requirement.specifier.contains(newest[_canonical(requirement.name)]), (
            f"{requirement} refuses the newest release, {newest[_canonical(requirement.name)]}"
        )


@pytest.mark.parametrize("next_release", ["minor", "major"])
def test_only_the_reasoned_caps_bound_a_dependency_from_above(next_release):
    """A range without a cap admits the next minor and the next major release of its newest; a cap stands only
    where pyproject.toml gives its reason on the line above ("# cap: ...")."""
    text = (ROOT / "pyproject.toml").read_text()
    lines = text[text.index("[project]") : text.index("[project.scripts]")].splitlines()
    newest = {_canonical(row["package"]): Version(row["newest"]) for row in _rows("pypi-newest.tsv")}
    capped = set()
    for i, line in enumerate(lines):
        for text in re.findall(r'"([A-Za-z][^"]*(?:>=|<)[^"]*)"', line):
            requirement = Requirement(text)
            if any(spec.operator in ("<", "<=", "==", "~=") for spec in requirement.specifier):
                assert "# cap:" in lines[i - 1] or "(cap:" in lines[i - 1], f"{text}: a cap without its reason"
                capped.add(requirement.name)
                continue
            v = newest[_canonical(requirement.name)]
            following = (
                Version(f"{v.major}.{v.minor + 1}.0") if next_release == "minor" else Version(f"{v.major + 1}.0.0")
            )
            assert requirement.specifier.contains(following), f"{text} refuses {following}"
    assert capped == {"meshcat", "nbgrader"}


@pytest.mark.parametrize("environment", ["environment.yml", "environment-dev.yml"])
def test_each_conda_spec_admits_what_conda_forge_has_on_every_platform(environment):
    """Each spec of the environment files, on its own, admits a version conda-forge lists for linux-64,
    linux-aarch64, osx-64, osx-arm64 and win-64 (tests/reference/conda-forge.tsv, which says where each row was
    read). Whether the specs fit together is the solver's question: tests/test_conda_solve.py."""
    forge = {row["package"]: row for row in _rows("conda-forge.tsv")}
    text = (ROOT / environment).read_text()
    specs = {}
    for line in text[text.index("dependencies:") :].splitlines():
        if m := re.match(r"\s*-\s+([A-Za-z0-9_.\-]+)(\S*)", line):
            specs[m[1]] = m[2]
    assert {"pybullet", "pytorch-cpu", "numpy"} <= set(specs)
    for package, spec in specs.items():
        row = forge.get(package)
        assert row is not None, f"{package}: not in tests/reference/conda-forge.tsv"
        assert row["source"].strip(), f"{package}: the reference file does not say where it was read"
        for platform in PLATFORMS:
            version = row[platform].strip()
            assert version not in ("", "-"), f"{package} has no conda-forge build for {platform}"
            assert SpecifierSet(spec.split(";")[0]).contains(version, prereleases=True), (
                f"{package}{spec} refuses conda-forge's {version} on {platform}"
            )
