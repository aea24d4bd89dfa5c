"""The conda route solves: a real conda solver (py-rattler, the rattler project's solver) solves environment.yml and
environment-dev.yml for linux-64, linux-aarch64, osx-64, osx-arm64 and win-64 against conda-forge's records as the
feedstocks' recipes give them (tests/reference/conda-forge-records.tsv, which says where each record was read and
which ones are modelled). The records are written as a local channel in a temporary folder: no network.

Checking each line of an environment file on its own says nothing about whether the lines fit together: conda-forge's
nbmake requires nbclient <0.7 and its stable-baselines3 gymnasium <1.3, both below what the course asks. Only a
solve over the whole file sees that. The route's pip step (``--no-deps``) must then find every requirement of what it
installs already in the solved environment, and never pybullet, which pip would build from source."""

import asyncio
import json
import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet

rattler = pytest.importorskip("rattler")  # the test extra's; CI's Colab leg runs without it
import yaml  # noqa: E402 (after the skip: only the test extra brings it)
from rattler.exceptions import SolverError  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "tests" / "reference"
PLATFORMS = ("linux-64", "linux-aarch64", "osx-64", "osx-arm64", "win-64")
ENVIRONMENTS = ("environment.yml", "environment-dev.yml")
#: The virtual packages a conda client reports on each platform (system facts, not packages to install).
VIRTUAL = {
    "linux-64": [("__unix", "0"), ("__linux", "6.8"), ("__glibc", "2.28"), ("__archspec", "1")],
    "linux-aarch64": [("__unix", "0"), ("__linux", "6.8"), ("__glibc", "2.28"), ("__archspec", "1")],
    "osx-64": [("__unix", "0"), ("__osx", "13.0"), ("__archspec", "1")],
    "osx-arm64": [("__unix", "0"), ("__osx", "14.0"), ("__archspec", "1")],
    "win-64": [("__win", "0"), ("__archspec", "1")],
}
#: Which platforms a requirement's selector in the reference file means.
SELECTORS = {
    "win": {"win-64"},
    "osx": {"osx-64", "osx-arm64"},
    "linux": {"linux-64", "linux-aarch64"},
    "unix": {"linux-64", "linux-aarch64", "osx-64", "osx-arm64"},
}
#: What only the tests, the benchmarks or a teacher use: never in a learner's environment.
TOOLING = {
    "pytest",
    "pytest-xdist",
    "nbmake",
    "ray-core",
    "ray-default",
    "nbgrader",
    "sb3-contrib",
    "stable-baselines3",
    "websocket-client",
}
#: PyPI's names for conda-forge packages that conda-forge names otherwise.
PYPI_TO_CONDA = {"torch": "pytorch"}


def _table(name: str) -> list[dict]:
    lines = [line for line in (REFERENCE / name).read_text().splitlines() if line and not line.startswith("#")]
    header = lines[0].split("\t")
    return [dict(zip(header, line.split("\t"))) for line in lines[1:]]


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(" ; ") if part.strip()]


def _for_platform(specs: list[str], platform: str) -> list[str]:
    """The requirements that apply on ``platform``: "[win] colorama" only on win-64, "[not osx] ..." off macOS."""
    kept = []
    for spec in specs:
        if m := re.match(r"\[(not )?(\w+)\] (.+)", spec):
            if (platform in SELECTORS[m[2]]) != bool(m[1]):
                kept.append(m[3])
        else:
            kept.append(spec)
    return kept


def conda_records(platform: str) -> dict[str, list[dict]]:
    """The reference file's records for ``platform``, as repodata.json entries by subdir ("noarch" or the
    platform): a row with Python versions becomes one build per version, pinned to it as conda-forge pins them."""
    by_subdir = {"noarch": [], platform: []}
    for row in _table("conda-forge-records.tsv"):
        noarch_row = row["platforms"] == "noarch"
        if not noarch_row and row["platforms"] != "all" and platform not in row["platforms"].split():
            continue
        pythons = [None] if row["python"] in ("-", "noarch") else row["python"].split()
        for py in pythons:
            depends = _for_platform(_split(row["depends"]), platform)
            build = row["build"]
            if py is not None:
                tag = py.replace(".", "")
                major, minor = py.split(".")
                depends += [f"python >={py},<{major}.{int(minor) + 1}.0a0", f"python_abi {py}.* *_cp{tag}"]
                build = build.replace("{py}", tag)
            record = {
                "name": row["name"],
                "version": row["version"],
                "build": build,
                "build_number": int(row["build_number"]),
                "depends": depends,
                "constrains": _for_platform(_split(row["constrains"]), platform),
                "subdir": "noarch" if noarch_row else platform,
            }
            if row["python"] == "noarch":
                record["noarch"] = "python"
            elif noarch_row:
                record["noarch"] = "generic"
            by_subdir[record["subdir"]].append(record)
    return by_subdir


def write_channel(platform: str, folder: Path) -> list:
    """A local conda channel in ``folder`` (``<subdir>/repodata.json``) and the solver's view of it."""
    channel = rattler.Channel(str(folder))
    sources = []
    for subdir, records in conda_records(platform).items():
        (folder / subdir).mkdir(parents=True, exist_ok=True)
        packages = {f"{r['name']}-{r['version']}-{r['build']}.conda": r for r in records}
        path = folder / subdir / "repodata.json"
        path.write_text(json.dumps({"info": {"subdir": subdir}, "packages": {}, "packages.conda": packages}))
        sources.append(rattler.SparseRepoData(channel, subdir, path))
    return sources


def environment_specs(name: str) -> list[str]:
    """An environment file's conda specs, as conda reads them."""
    return [str(spec) for spec in yaml.safe_load((ROOT / name).read_text())["dependencies"]]


def solve(specs: list[str], platform: str, folder: Path) -> dict[str, str]:
    """name -> version of what a conda client would install on ``platform`` for ``specs``."""
    virtual = [
        rattler.GenericVirtualPackage(rattler.PackageName(n), rattler.Version(v), rattler.BuildString("0"))
        for n, v in VIRTUAL[platform]
    ]
    records = asyncio.run(
        rattler.solve_with_sparse_repodata(specs, write_channel(platform, folder), virtual_packages=virtual)
    )
    return {record.name.normalized: str(record.version) for record in records}


def pip_step(name: str) -> list[str]:
    """The route's pip command, as the environment file's header gives it."""
    commands = [
        line.strip("# ").strip()
        for line in (ROOT / name).read_text().splitlines()
        if line.startswith("#") and "pip install" in line
    ]
    assert len(commands) == 1, f"{name}: its header gives no single pip command"
    return commands[0].split("pip install", 1)[1].split()


def test_the_reference_records_are_a_closed_world_with_sources():
    """Every requirement names a package the file holds (or a virtual package), and every row says where it
    was read; the packages that carry the constraints in question are real records, not stubs."""
    rows = _table("conda-forge-records.tsv")
    names = {row["name"] for row in rows}
    for row in rows:
        assert row["source"].strip() and re.fullmatch(r"\d{4}-\d{2}-\d{2}", row["read_on"]), row["name"]
        for spec in _split(row["depends"]):
            name = re.sub(r"^\[[^\]]+\] ", "", spec).split()[0]
            assert name in names or name.startswith("__"), f"{row['name']} requires {name}, which is not modelled"
    real = {row["name"] for row in rows if row["kind"] == "real"}
    assert {
        "python",
        "numpy",
        "pytorch",
        "pytorch-cpu",
        "pybullet",
        "gymnasium",
        "nbclient",
        "nbmake",
        "stable-baselines3",
        "sb3-contrib",
        "ray-core",
        "click",
    } <= real
    for package in {
        spec.split(">")[0].split("<")[0].split("=")[0] for env in ENVIRONMENTS for spec in environment_specs(env)
    }:
        assert package in real, f"{package} (asked for by an environment file) is a stub"


@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_each_environment_file_takes_conda_forge_alone(environment):
    """The solve below knows conda-forge's records only; "nodefaults" keeps conda from adding Anaconda's defaults
    channel where its configuration lists it (conda's env installer drops defaults when it sees the word)."""
    assert yaml.safe_load((ROOT / environment).read_text())["channels"] == ["conda-forge", "nodefaults"]


@pytest.mark.parametrize("platform", PLATFORMS)
@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_each_environment_file_solves(environment, platform, tmp_path):
    solved = solve(environment_specs(environment), platform, tmp_path)
    # what the course needs, from conda-forge, at the versions the course asks for
    assert solved["pybullet"] == "3.25"
    assert SpecifierSet(">=1.3").contains(solved["gymnasium"])
    assert SpecifierSet(">=0.10").contains(solved["nbclient"])
    assert SpecifierSet(">=3.11").contains(solved["python"])
    if environment == "environment-dev.yml":
        assert {"pytest", "pytest-xdist", "ray-default", "nbgrader"} <= set(solved)


@pytest.mark.parametrize("platform", PLATFORMS)
def test_a_learners_environment_holds_no_test_tooling(platform, tmp_path):
    solved = solve(environment_specs("environment.yml"), platform, tmp_path)
    assert not TOOLING & set(solved), sorted(TOOLING & set(solved))


@pytest.mark.parametrize("platform", PLATFORMS)
def test_the_dev_routes_pip_step_finds_its_requirements_in_the_environment(platform, tmp_path):
    """What environment-dev.yml's route installs with ``pip install --no-deps`` (nbmake, stable-baselines3,
    sb3-contrib) requires only what the solved environment holds, at versions it admits (PyPI's metadata:
    tests/reference/pypi-no-deps-requires.tsv)."""
    solved = solve(environment_specs("environment-dev.yml"), platform, tmp_path)
    by_pip = {
        Requirement(arg.strip('"')).name
        for arg in pip_step("environment-dev.yml")
        if not arg.startswith("-") and arg != "."
    }
    declared = {row["package"]: row for row in _table("pypi-no-deps-requires.tsv")}
    assert by_pip == set(declared)
    for package, row in declared.items():
        for text in _split(row["requires"]):
            requirement = Requirement(text)
            name = re.sub(r"[-_.]+", "-", requirement.name).lower()
            if name in by_pip:
                version = declared[name]["version"]
            else:
                name = PYPI_TO_CONDA.get(name, name)
                assert name in solved, f"{package} needs {requirement}; the environment has no {name}"
                version = solved[name]
            assert requirement.specifier.contains(version), f"{package} needs {requirement}, not {version}"


@pytest.mark.parametrize("platform", PLATFORMS)
@pytest.mark.parametrize(("tool", "blocked_by"), [("nbmake>=1.5", "nbclient"), ("sb3-contrib>=2.8", "gymnasium")])
def test_conda_forges_nbmake_and_sb3_cannot_join_the_course(tool, blocked_by, platform, tmp_path):
    """Why those two come from pip: conda-forge's nbmake caps nbclient below the book's floor, its
    stable-baselines3 caps gymnasium below the course's. The solver says so, naming the package."""
    with pytest.raises(SolverError, match=blocked_by):
        solve(environment_specs("environment.yml") + [tool], platform, tmp_path)


@pytest.mark.parametrize("environment", ENVIRONMENTS)
def test_the_conda_route_never_lets_pip_build_pybullet(environment, tmp_path):
    """pip must never replace a conda package (conda-forge's pybullet calls itself 3.2.5, below the pip floor
    on Linux x86_64 that a plain install would try to meet by building from source): no pip section (a
    requirements line cannot say --no-deps), the route's pip step has --no-deps and does not name pybullet,
    and conda's solve brings pybullet (test_each_environment_file_solves)."""
    assert "- pip:" not in (ROOT / environment).read_text()
    args = pip_step(environment)
    assert "--no-deps" in args
    assert not [arg for arg in args if "pybullet" in arg.lower()]
    assert "pybullet" in {spec.split(">")[0] for spec in environment_specs(environment)}


def test_the_routes_are_written_the_same_everywhere():
    """The README, docs/install.md and chapter 00's check give the learner's command as environment.yml's header
    does; docs/install.md gives the dev route as environment-dev.yml's header does, and the README points to it."""
    from vdtutorial.course.install_check import CONDA_ROUTE

    learner = "conda env create -f environment.yml && conda activate vdtutorial && pip install --no-deps -e ."
    assert learner in (ROOT / "environment.yml").read_text() and CONDA_ROUTE == learner
    dev = (ROOT / "environment-dev.yml").read_text()
    create = "conda env create -f environment-dev.yml && conda activate vdtutorial-dev"
    install = "pip install " + " ".join(pip_step("environment-dev.yml"))
    assert create in dev and install in dev
    readme, install_page = (ROOT / "README.md").read_text(), (ROOT / "docs" / "install.md").read_text()
    assert learner in readme and learner in install_page
    assert f"{create} && {install}" in install_page
    assert "environment-dev.yml" in readme


@pytest.mark.parametrize("conda", [True, False])
def test_chapter_00_sends_a_conda_learner_back_to_the_environment_file(conda, tmp_path, monkeypatch):
    """A package missing from a conda environment is fixed from environment.yml; elsewhere from pip."""
    from vdtutorial.course import install_check

    if conda:
        (tmp_path / "conda-meta").mkdir()
    monkeypatch.setattr(install_check.sys, "prefix", str(tmp_path))
    [(status, _, message)] = install_check.package_checks(names=("no-such-package-vdtutorial",))
    assert status == "FIX"
    assert ("conda env update -f environment.yml" in message) == conda
    assert ("pip install" in message) == (not conda)
