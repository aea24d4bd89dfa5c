"""Where learners run the package: the chapters written out of an installation, the folders they then read
and write, the records that must not name the machine that made them, and chapter 00's install checks."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from vdtutorial.course import install_check
from vdtutorial.course.chapters import EditedFilesError, shipped_files, write_notebooks
from vdtutorial.experiments.paths import recorded_path
from vdtutorial.settings import BOOK_RECORD, data_dir

ROOT = Path(__file__).resolve().parent.parent


def test_notebooks_writes_every_chapter_and_data_file_and_records_them(tmp_path):
    book = write_notebooks(tmp_path / "book")
    chapters = sorted(p.name for p in (ROOT / "notebooks").glob("*.ipynb"))
    assert sorted(p.name for p in (book.dest / "notebooks").glob("*.ipynb")) == chapters
    assert book.chapters + book.appendices == len(chapters) and book.data_files == sum(
        1 for p in shipped_files() if p.parts[0] == "data"
    )
    assert (book.dest / "data/results/fig4/fig4.json").read_bytes() == (
        ROOT / "data/results/fig4/fig4.json"
    ).read_bytes()
    record = json.loads((book.dest / BOOK_RECORD).read_text())
    assert set(record["files"]) == {p.as_posix() for p in shipped_files()}


def test_notebooks_refuses_to_overwrite_an_edited_chapter_unless_forced(tmp_path):
    dest = tmp_path / "book"
    write_notebooks(dest)
    write_notebooks(dest)  # untouched: written again without a word
    chapter = dest / "notebooks" / "04_sparse_variational_dropout.ipynb"
    chapter.write_text(chapter.read_text().replace("log", "LOG", 1))
    edited = chapter.read_text()
    with pytest.raises(EditedFilesError, match="04_sparse_variational_dropout.ipynb.*--force"):
        write_notebooks(dest)
    assert chapter.read_text() == edited  # refused before anything was written
    write_notebooks(dest, force=True)
    assert chapter.read_text() == (ROOT / "notebooks" / chapter.name).read_text()


def test_a_foreign_file_in_the_way_counts_as_edited(tmp_path):
    (tmp_path / "notebooks").mkdir()
    (tmp_path / "notebooks" / "00_start_here.ipynb").write_text("{}")
    with pytest.raises(EditedFilesError):
        write_notebooks(tmp_path)


def test_the_command_refuses_in_one_line(tmp_path, capsys):
    from vdtutorial.__main__ import main

    (tmp_path / "file").write_text("")
    assert main(["notebooks", str(tmp_path / "file")]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "is a file, not a folder" in errors[0]


def test_chapters_run_from_a_written_folder_read_and_write_there(tmp_path):
    write_notebooks(tmp_path / "book")
    where = subprocess.run(
        [
            sys.executable,
            "-c",
            "from vdtutorial.experiments import paths as p; print(p.data_dir()); print(p.runs_dir())",
        ],
        cwd=tmp_path / "book" / "notebooks",
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert [Path(p) for p in where] == [tmp_path / "book" / "data", tmp_path / "book" / "runs"]


def test_recorded_paths_are_relative_to_the_folder_holding_data():
    assert recorded_path(data_dir() / "demos" / "x.npz") == "data/demos/x.npz"
    assert recorded_path(data_dir().parent / "runs" / "state") == "runs/state"
    assert recorded_path("/elsewhere/scratch") == "/elsewhere/scratch"  # outside: a user's own folder, as given


def test_a_path_under_a_linked_runs_folder_is_recorded_relative(tmp_path, monkeypatch):
    """A worktree whose ``runs`` links to the main checkout's (the long image runs): its record says ``runs/...``,
    not the absolute folder the link leads to; a link out of the checkout from elsewhere is still followed."""
    checkout, other = tmp_path / "worktree", tmp_path / "main"
    (checkout / "data").mkdir(parents=True)
    (other / "runs" / "fig5").mkdir(parents=True)
    (checkout / "runs").symlink_to(other / "runs")
    (tmp_path / "scratch").symlink_to(checkout / "runs")
    monkeypatch.setenv("VDTUTORIAL_DATA", str(checkout / "data"))
    assert recorded_path(checkout / "runs" / "fig5" / "state") == "runs/fig5/state"
    monkeypatch.chdir(checkout)
    assert recorded_path("runs/fig5/state") == "runs/fig5/state"
    assert recorded_path(tmp_path / "scratch" / "fig5") == str(other / "runs" / "fig5")


class _FakeDistribution:
    def __init__(self, **files):
        self.files = files

    def read_text(self, name):
        return self.files.get(name)


@pytest.mark.parametrize(
    "files, route",
    [
        ({"INSTALLER": "pip\n", "WHEEL": "Wheel-Version: 1.0\nTag: cp311-cp311-manylinux_2_17_x86_64\n"}, "wheel"),
        ({"INSTALLER": "pip\n", "WHEEL": "Wheel-Version: 1.0\nTag: cp313-cp313-linux_x86_64\n"}, "source"),
        ({"INSTALLER": "conda\n"}, "conda"),
    ],
)
def test_pybullet_route_is_read_from_its_metadata(files, route):
    assert install_check.pybullet_route(_FakeDistribution(**files)) == route


def test_pybullet_without_numpy_is_a_fix_with_the_rebuild_command(monkeypatch):
    import pybullet

    monkeypatch.setattr(pybullet, "isNumpyEnabled", lambda: 0)
    monkeypatch.setattr(install_check, "pybullet_route", lambda: "source")
    rows = dict((item, (status, message)) for status, item, message in install_check.pybullet_checks())
    status, message = rows["pybullet numpy"]
    assert status == "FIX" and "--no-build-isolation" in message and "--no-cache-dir" in message


def test_this_machine_passes_the_checks_it_runs_ci_on():
    rows = install_check.environment_checks()
    assert [row for row in rows if row[0] == "FIX"] == []
    assert ("ok", "pybullet numpy", "built with numpy support (fast camera images)") in rows


def test_a_missing_pybullet_says_how_to_get_it_on_this_machine():
    hide = (
        "import importlib.util as u; real = u.find_spec; "
        "u.find_spec = lambda name, *a: None if name == 'pybullet' else real(name, *a); import vdtutorial"
    )
    run = subprocess.run([sys.executable, "-c", hide], capture_output=True, text=True)
    assert run.returncode != 0
    assert f"pybullet is not installed: {install_check.missing_pybullet()}" in run.stderr.splitlines()[-1]


@pytest.mark.parametrize(
    "system, machine, version, route, advice",
    [
        ("Linux", "x86_64", (3, 11), "Linux x86_64", "a prebuilt wheel"),
        ("Linux", "x86_64", (3, 13), "Linux x86_64", "--no-build-isolation"),
        ("Linux", "aarch64", (3, 11), "Linux aarch64", "pip install --no-deps -e ."),
        ("Darwin", "arm64", (3, 12), "macOS arm64", "conda env create -f environment.yml"),
        ("Darwin", "x86_64", (3, 12), "macOS x86_64", "conda env create -f environment.yml"),
        ("Windows", "AMD64", (3, 11), "Windows", "conda env create -f environment.yml"),
    ],
)
def test_the_advice_for_a_missing_pybullet_follows_the_platform(monkeypatch, system, machine, version, route, advice):
    monkeypatch.setattr(install_check.platform, "system", lambda: system)
    monkeypatch.setattr(install_check.platform, "machine", lambda: machine)
    monkeypatch.setattr(install_check.sys, "version_info", (*version, 0, "final", 0))
    monkeypatch.setattr(install_check, "on_colab", lambda: False)
    assert install_check.platform_route() == route
    assert advice in install_check.missing_pybullet()


def test_colab_is_sent_to_the_readme_cell(monkeypatch):
    monkeypatch.setattr(install_check, "on_colab", lambda: True)
    assert install_check.platform_route() == "Google Colab"
    assert "Colab cell" in install_check.missing_pybullet()


def test_install_check_and_the_readme_give_each_platform_the_same_route():
    """One route per platform, the same in the README's table and in chapter 00's check."""
    readme = (ROOT / "README.md").read_text()
    for name, route in install_check.ROUTES.items():
        row = next((line for line in readme.splitlines() if line.startswith(f"| {name} |")), None)
        assert row is not None, f"the README's install table has no row for {name}"
        cell = row.split("|")[2]
        if route.startswith("conda-forge"):
            assert "conda-forge" in cell and install_check.CONDA_ROUTE in readme
        elif name == "Google Colab":
            assert "cell" in cell
        else:
            assert "pip" in cell


def test_an_image_env_without_numpy_support_warns_once(monkeypatch):
    import warnings

    import gymnasium as gym
    import pybullet

    from vdtutorial.envs import bullet

    monkeypatch.setattr(pybullet, "isNumpyEnabled", lambda: 0)
    bullet.warn_if_images_are_slow.cache_clear()
    env = gym.make("vdtutorial/JacoReach-v0", obs_mode="rgbd", image_size=32)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env.reset(seed=0)
            env.step(env.action_space.sample())
            env.unwrapped.scene.render_rgbd()
    finally:
        env.close()
        bullet.warn_if_images_are_slow.cache_clear()
    slow = [w for w in caught if "without numpy support" in str(w.message)]
    assert len(slow) == 1 and "Chapter 00's install check prints the command" in str(slow[0].message)
