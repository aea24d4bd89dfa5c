"""Shared test settings."""

import importlib.util
import runpy
from pathlib import Path

# First, before numpy loads: the AVX2 kernel pins (vdtutorial/runner/kernels.py), which the shipped-row regeneration
# tests need. The file runs by its path, since importing the package would load numpy first; the installed
# package's copy is the one found, so this works from a wheel as from a clone.
_PACKAGE = Path(importlib.util.find_spec("vdtutorial").submodule_search_locations[0])
runpy.run_path(str(_PACKAGE / "runner" / "kernels.py"))["pin_vector_kernels"]()

import json  # noqa: E402
import platform  # noqa: E402

import gymnasium  # noqa: E402
import numpy  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

import vdtutorial  # noqa: E402


def numerics_here() -> dict:
    """The versions that decide a run's floating-point results, as shipped records name them."""
    return {
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "gymnasium": gymnasium.__version__,
        "python": ".".join(platform.python_version_tuple()[:2]),
    }


def require_recorded_numerics(record_path: Path) -> None:
    """Skip, naming both sets of versions, unless this process runs the versions the shipped record
    ``record_path`` was made under: results regenerate bit for bit only there (CI's Python 3.11 leg installs
    them from constraints-py311.txt). Elsewhere a difference is not a bug, so it must not fail a test."""
    made = json.loads(Path(record_path).read_text())["versions"]
    made = {**made, "python": ".".join(made["python"].split(".")[:2])}
    here = numerics_here()
    if any(made[key] != value for key, value in here.items()):
        pytest.skip(
            f"exact regeneration holds under the recorded versions "
            f"({', '.join(f'{k} {made[k]}' for k in here)}); this is {', '.join(f'{k} {v}' for k, v in here.items())}"
        )


def require_locked(package: str) -> None:
    """Skip, naming both versions, unless ``package`` is the version constraints-py311.txt locks: the shipped
    statistics (intervals from scipy's t, detectable differences from its noncentral t) were computed under it, and
    another release may round them otherwise (CI's Colab leg has scipy 1.16)."""
    import importlib.metadata as md

    lock = Path(__file__).resolve().parent.parent / "constraints-py311.txt"
    locked = dict(
        line.split("==") for line in lock.read_text().splitlines() if "==" in line and not line.startswith("#")
    )
    if md.version(package) != locked[package]:
        pytest.skip(
            f"the shipped statistics were computed with {package} {locked[package]}; this is {md.version(package)}"
        )


@pytest.fixture(autouse=True)
def one_thread():
    """Tiny tensors: one torch thread avoids synchronisation costs on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def pytest_report_header(config):
    """Which package and which numerics this run tests (CI's two legs differ in both)."""
    import pybullet

    numerics = ", ".join(f"{k} {v}" for k, v in numerics_here().items())
    return (
        f"vdtutorial from {Path(vdtutorial.__file__).parent}; {numerics}; "
        f"pybullet.isNumpyEnabled() = {bool(pybullet.isNumpyEnabled())}"
    )


def assert_expert_labels(demos, episodes) -> None:
    """Every state of the reach ``episodes`` of ``demos`` is labelled with the noiseless IK expert's action in it
    (eq. 8), whoever acted there: G is rebuilt for each episode's cup and eq. 10 asked again."""
    from vdtutorial.envs import ENV_IDS
    from vdtutorial.expert import IKExpert

    env = gymnasium.make(ENV_IDS["reach"], obs_mode="state")
    expert = IKExpert(env)
    for ep in episodes:
        rows = numpy.flatnonzero(demos.episode == ep)
        env.reset(options={"cup_xy": demos.cup[rows[0], :2]})
        expert.reset()
        for i in rows:
            numpy.testing.assert_allclose(
                expert.action(demos.joints[i].astype(numpy.float64)), demos.actions[i], atol=1e-5
            )
    env.close()
