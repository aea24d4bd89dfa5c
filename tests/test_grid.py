"""Restartable grids: a grid killed with SIGKILL and run again gives the rows of an uninterrupted grid;
saved runs of other settings are an error (or discarded with restart); the defaults of the experiments."""

import io
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from vdtutorial.experiments import (
    SUBSAMPLED_FISHER_CONFIG,
    Curve,
    ExperimentResult,
    ResumeError,
    RunSpec,
    default_trpo_config,
    format_summary,
    read_rows,
    results_file,
    run_experiment,
)
from vdtutorial.demos import demo_path
from vdtutorial.experiments import finetune
from vdtutorial.runner import resume as resume_module
from vdtutorial.experiments import pipeline as pipeline_module
from vdtutorial.runner.compressed import GZIP_MAGIC, save_compressed
from vdtutorial.runner.resume import read_run_state, settings_differences
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.settings import is_quick
from vdtutorial.trpo import TIMING_COLUMNS, TRPOConfig

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

#: 20 iterations per TRPO run, a state saved after each: a wide window in which to kill the grid.
COMMAND = [
    sys.executable,
    "-m",
    "vdtutorial",
    "experiment",
    "fig4",
    "--seeds",
    "0",
    "--steps",
    "4000",
    "--workers",
    "2",
    "--checkpoint-every",
    "1",
]
ITERATIONS = 20


def _without_wall_time(rows):
    return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]


def _rows_without_wall_time(folder):
    return _without_wall_time(read_rows(results_file(folder, "fig4")))


def _saved_iterations(runs_dir) -> dict[str, int]:
    """Rows saved so far by each TRPO run of the grid (the expert's state has no iteration)."""
    saved = {}
    for path in runs_dir.glob("*.pt"):
        try:
            state = read_run_state(path)
        except ResumeError:  # a file being replaced right now: look again next time
            continue
        if "iteration" in state:
            saved[path.stem] = state["iteration"]
    return saved


@pytest.mark.skipif(not is_quick(), reason="runs the experiment command three times: quick mode only")
def test_a_grid_killed_with_sigkill_resumes_to_the_rows_of_an_uninterrupted_grid(tmp_path):
    env = {**os.environ, "VDTUTORIAL_QUICK": "1"}
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    subprocess.run([*COMMAND, "--out", str(whole)], env=env, check=True, capture_output=True)
    # the killed grid reuses the pre-trained policies (what is tested is the RL stage, not pre-training)
    shutil.copytree(whole / "checkpoints", killed / "checkpoints")

    grid = subprocess.Popen(
        [*COMMAND, "--out", str(killed)],
        env=env,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and grid.poll() is None:
        saved = _saved_iterations(killed / "runs")
        if any(0 < n < ITERATIONS for n in saved.values()):
            break
        time.sleep(0.02)
    os.killpg(grid.pid, signal.SIGKILL)  # the grid and its workers: a closed laptop, a preempted node
    grid.wait()
    at_kill = _saved_iterations(killed / "runs")
    assert grid.returncode == -signal.SIGKILL
    assert any(0 < n < ITERATIONS for n in at_kill.values()), f"not killed mid-run: {at_kill}"
    assert not results_file(killed, "fig4").exists()

    again = subprocess.run([*COMMAND, "--out", str(killed)], env=env, check=True, capture_output=True, text=True)
    assert "0 to resume" not in again.stdout and "to resume" in again.stdout
    assert _rows_without_wall_time(killed) == _rows_without_wall_time(whole)
    record = json.loads((killed / "fig4.json").read_text())
    resumed = {run["name"]: run["resumed_at_iteration"] for run in record["runs"]}
    assert any(resumed[name] == n for name, n in at_kill.items() if 0 < n < ITERATIONS)
    # the same machine and numerics before and after the kill: one stretch per run, from its first iteration
    assert all([s["from_iteration"] for s in run["numerics_stretches"]] == [0] for run in record["runs"])


@pytest.mark.skipif(not is_quick(), reason="runs the experiment command: quick mode only")
def test_ctrl_c_stops_a_grid_with_workers_with_one_line(tmp_path):
    """SIGINT reaches the command and its workers (a terminal's Ctrl-C goes to the whole process group): the
    command answers with its one line and exit code 130, the workers with nothing."""
    env = {**os.environ, "VDTUTORIAL_QUICK": "1"}

    def like_a_terminal():  # a test runner's worker may ignore SIGINT, and an ignored signal stays ignored in a child
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    longer = [*COMMAND[: COMMAND.index("--steps") + 1], "40000", *COMMAND[COMMAND.index("--steps") + 2 :]]
    grid = subprocess.Popen(
        [*longer, "--out", str(tmp_path)],
        env=env,
        start_new_session=True,  # 200 iterations a run
        preexec_fn=like_a_terminal,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and grid.poll() is None and not _saved_iterations(tmp_path / "runs"):
        time.sleep(0.05)
    os.killpg(grid.pid, signal.SIGINT)
    _, err = grid.communicate(timeout=120)
    assert grid.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert err.count("interrupted: ") == 1 and "(without --restart)" in err


def _tiny_grid(out, trpo_config=None, **kwargs):
    specs = [RunSpec("none", "reach", None, None, seed, "state", 400, "none") for seed in (0, 1)]
    return run_experiment(
        "tiny", specs, "tiny", out, 1, window=2, command="test", trpo_config=trpo_config, progress=False, **kwargs
    )


def test_saved_runs_of_other_settings_are_an_error_and_restart_discards_them(tmp_path):
    first = _tiny_grid(tmp_path, checkpoint_every=1)
    again = _tiny_grid(tmp_path)  # the same grid: every run is found finished and not run again
    assert [r["wall_time"] for r in again.rows] == [r["wall_time"] for r in first.rows]
    runs = json.loads((tmp_path / "tiny.json").read_text())["runs"]
    assert [run["resumed_at_iteration"] for run in runs] == [None, None]  # found finished, not started at 0
    other = TRPOConfig(max_kl=0.02)
    with pytest.raises(ResumeError, match=r"max_kl: 0\.01 -> 0\.02.*--restart"):
        _tiny_grid(tmp_path, other)
    with pytest.raises(ResumeError, match="more than the 1 asked for"):
        run_experiment(
            "tiny",
            [RunSpec("none", "reach", None, None, 0, "state", 200, "none")],
            "tiny",
            tmp_path,
            1,
            window=2,
            progress=False,
        )
    restarted = _tiny_grid(tmp_path, other, restart=True)
    assert restarted.rows != first.rows
    assert all(r["mean_kl"] <= 0.02 + 1e-7 for r in restarted.rows)
    assert json.loads((tmp_path / "tiny.json").read_text())["trpo_config"]["max_kl"] == 0.02


def test_a_longer_budget_extends_finished_runs_to_the_rows_of_a_longer_run(tmp_path):
    short = run_experiment(
        "tiny",
        [RunSpec("none", "reach", None, None, 0, "state", 400, "none")],
        "tiny",
        tmp_path / "a",
        1,
        window=2,
        progress=False,
    )
    longer = run_experiment(
        "tiny",
        [RunSpec("none", "reach", None, None, 0, "state", 800, "none")],
        "tiny",
        tmp_path / "a",
        1,
        window=2,
        progress=False,
    )
    fresh = run_experiment(
        "tiny",
        [RunSpec("none", "reach", None, None, 0, "state", 800, "none")],
        "tiny",
        tmp_path / "b",
        1,
        window=2,
        progress=False,
    )
    drop = _without_wall_time
    assert drop(longer.rows[:2]) == drop(short.rows) and drop(longer.rows) == drop(fresh.rows)


def test_a_resumed_run_does_not_fit_its_start_sigma_again(tmp_path, monkeypatch):
    """A resumed pre-trained run takes every parameter from its state: its network is built from the default
    checkpoint, the start sigma is not fitted again (minutes for an image policy), and the rows are those of an
    uninterrupted run."""
    config = PretrainConfig(epochs=1, initial_sigma="spread")

    def run(steps, state_path=None):
        return finetune(
            "vd",
            "reach",
            demo_path("reach", 2000, 0.5, 0),
            total_steps=steps,
            pretrain_config=config,
            checkpoints_root=tmp_path,
            state_path=state_path,
            checkpoint_every=1,
        )[1]

    whole = run(800)
    run(400, tmp_path / "state.pt")
    fitted = list((tmp_path / "checkpoints").glob("*initsigma-spread.pt"))
    assert len(fitted) == 1
    fitted[0].unlink()

    def no_fit(*args, **kwargs):
        raise AssertionError("the start sigma was fitted again for a resumed run")

    monkeypatch.setattr(pipeline_module, "set_initial_sigma", no_fit)
    resumed = run(800, tmp_path / "state.pt")
    assert len(resumed) == 4 and _without_wall_time(resumed) == _without_wall_time(whole)
    assert not fitted[0].exists()


def test_run_states_are_compressed_and_uncompressed_states_still_resume(tmp_path):
    """States are written gzip-compressed; a state in the earlier, uncompressed format (``torch.save``'s
    own) continues to the rows of an uninterrupted run, and its next save is compressed."""

    def run(steps, state_path=None):
        return finetune("none", "reach", total_steps=steps, state_path=state_path, checkpoint_every=1)[1]

    whole = run(800)
    path = tmp_path / "state.pt"
    run(400, path)
    compressed = path.read_bytes()
    assert compressed[:2] == GZIP_MAGIC
    state = read_run_state(path)
    assert state["iteration"] == 2 and state["run_settings"]["method"] == "none"
    uncompressed = io.BytesIO()
    torch.save(state, uncompressed)
    assert len(compressed) < 0.9 * len(uncompressed.getvalue())
    path.write_bytes(uncompressed.getvalue())
    resumed = run(800, path)
    assert len(resumed) == 4 and _without_wall_time(resumed) == _without_wall_time(whole)
    assert path.read_bytes()[:2] == GZIP_MAGIC


def test_the_global_random_states_are_restored_on_resume():
    """A run draws only from its own seeded generators today; the saved global states keep a resumed run
    exact should any part of it draw from torch's, numpy's or Python's global generator."""
    torch.manual_seed(1), np.random.seed(1), random.seed(1)
    saved = resume_module._rng_state()
    expected = (torch.rand(3), np.random.rand(3), [random.random() for _ in range(3)])
    torch.manual_seed(2), np.random.seed(2), random.seed(2)
    resume_module._set_rng_state(saved)
    drawn = (torch.rand(3), np.random.rand(3), [random.random() for _ in range(3)])
    assert torch.equal(drawn[0], expected[0]) and np.array_equal(drawn[1], expected[1]) and drawn[2] == expected[2]


def test_states_are_written_whole_through_a_temporary_file_of_their_own(tmp_path, monkeypatch):
    """Two processes saving the same run (two grids on one state folder) never share a temporary file,
    and a save that fails leaves the previous state and no temporary file behind."""
    path = tmp_path / "run.pt"
    resume_module.save_finished_rows(path, {"method": "expert"}, [{"successes": 1}], 1.0)
    names = []
    real_replace = os.replace

    def failing_replace(source, target):
        names.append(os.path.basename(source))
        raise OSError("disk full")

    monkeypatch.setattr(resume_module.os, "replace", failing_replace)
    for _ in range(2):
        with pytest.raises(OSError, match="disk full"):
            resume_module.save_finished_rows(path, {"method": "expert"}, [{"successes": 2}], 2.0)
    monkeypatch.setattr(resume_module.os, "replace", real_replace)
    assert len(set(names)) == 2 and all(name.startswith("run.pt.") and name.endswith(".tmp") for name in names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.pt"]
    assert read_run_state(path)["rows"] == [{"successes": 1}]


def test_a_state_saved_under_other_numerics_resumes_with_a_warning(tmp_path):
    """Another torch or other CPU kernels do not change what a run is (no error), but its rows may differ in
    the last digits from an uninterrupted run's: resuming says so, another CPU model included. A state saved
    before the numerics (or the CPU model) were recorded resumes silently."""
    import warnings

    path = tmp_path / "state.pt"
    here = resume_module.numerics()
    finetune("none", "reach", total_steps=200, state_path=path, checkpoint_every=1)
    state = read_run_state(path)
    assert state["numerics"] == here and state["numerics_stretches"] == [{"from_iteration": 0, **here}]
    old_torch = {**here, "torch": "1.0.0"}
    state["numerics"], state["numerics_stretches"] = old_torch, [{"from_iteration": 0, **old_torch}]
    save_compressed(state, path)
    with pytest.warns(UserWarning, match=r"other numerics \(torch: '1\.0\.0' -> .*last digits"):
        finetune("none", "reach", total_steps=400, state_path=path, checkpoint_every=1)
    state = read_run_state(path)
    assert state["numerics_stretches"] == [{"from_iteration": 0, **old_torch}, {"from_iteration": 1, **here}]
    state["numerics"] = {**state["numerics"], "cpu": "Intel(R) Xeon(R)"}
    save_compressed(state, path)
    with pytest.warns(UserWarning, match=r"other numerics \(cpu: 'Intel\(R\) Xeon\(R\)' -> "):
        finetune("none", "reach", total_steps=600, state_path=path, checkpoint_every=1)
    state = read_run_state(path)
    del state["numerics"]["cpu"]
    save_compressed(state, path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        finetune("none", "reach", total_steps=800, state_path=path, checkpoint_every=1)
    state = read_run_state(path)
    del state["numerics"], state["numerics_stretches"]  # as saved before either was kept
    save_compressed(state, path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        finetune("none", "reach", total_steps=1000, state_path=path, checkpoint_every=1)
    assert read_run_state(path)["numerics_stretches"] == [{"from_iteration": 4, **here}]


def test_a_state_saved_before_stretches_were_kept_counts_as_one_stretch_of_unknown_start():
    """Its last saved numerics are all it says; this process's numerics start a stretch only where they differ."""
    here = resume_module.numerics()
    assert resume_module.numerics_stretches({"numerics": here}, 7) == [{"from_iteration": None, **here}]
    no_cpu = {k: v for k, v in here.items() if k != "cpu"}
    assert resume_module.numerics_stretches({"numerics": no_cpu}, 7) == [
        {"from_iteration": None, **no_cpu},
        {"from_iteration": 7, **here},
    ]
    assert resume_module.numerics_stretches(None, 0) == [{"from_iteration": 0, **here}]


def test_settings_differences_name_nested_settings():
    saved = {"seed": 0, "trpo_config": {"max_kl": 0.01, "fvp_subsample": 1.0}}
    wanted = {"seed": 0, "trpo_config": {"max_kl": 0.01, "fvp_subsample": 0.1}}
    assert settings_differences(saved, wanted) == ["trpo_config.fvp_subsample: 1.0 -> 0.1"]
    assert settings_differences(saved, saved) == []


def test_the_whole_batch_fisher_is_the_default_everywhere_and_10_percent_the_control():
    assert default_trpo_config() == TRPOConfig()  # one setting for state and images: the function takes no mode
    assert TRPOConfig().fvp_subsample == 1.0 and SUBSAMPLED_FISHER_CONFIG.fvp_subsample == 0.1


def test_the_summary_of_a_single_seed_prints_no_nan_band():
    nan = [math.nan]
    curves = {
        "VD": Curve("VD", "vd", [200.0], [2.0], nan, nan, 1),
        "L2": Curve("L2", "l2", [200.0], [1.0], [0.5], [1.5], 3),
    }
    summary = {
        "final": {
            label: {"mean": c.mean[-1], "low": c.low[-1], "high": c.high[-1], "seeds": c.seeds}
            for label, c in curves.items()
        }
    }
    text = format_summary(ExperimentResult("fig4", "runs/fig4", [], curves, None, summary))
    assert "nan" not in text
    assert "final 2.00 (1 seed: no band from a single sample)" in text
    assert "final 1.00 (95% band 0.50 to 1.50, 3 seeds)" in text


def test_wall_time_estimate_on_hand_made_runs():
    from vdtutorial.experiments.estimate import distinct_runs, makespan

    assert makespan([3.0, 3.0, 3.0, 1.0], 2) == 6.0  # runs in order on the first free core: 3+3 | 3+1
    assert makespan([1.0, 2.0, 3.0], 5) == 3.0  # more cores than runs: the longest run
    assert makespan([], 4) == 0.0
    # Fig. 4's VD, L2, none; Fig. 5 adds VD and L2 on 2000 and 4000 samples; Fig. 6 on Sigma 0.05 and 0.25
    assert len(distinct_runs(["fig4", "fig5", "fig6"], seeds=(0,))) == 3 + 4 + 4


def test_run_seconds_adds_pretraining_only_where_no_checkpoint_is_shipped():
    from vdtutorial.experiments.estimate import distinct_runs, needs_pretraining, run_seconds

    runs = {(s.method, s.samples): s for s in distinct_runs(["fig4", "fig5"], seeds=(0,))}
    cost = {"vd": 1000.0, "l2": 400.0}
    assert not needs_pretraining(runs[("vd", 8000)])  # shipped rgbd checkpoint of Fig. 4's data set
    assert run_seconds(runs[("vd", 8000)], 100.0, cost, 50.0) == 3000.0 + 50.0
    assert needs_pretraining(runs[("l2", 2000)])  # no shipped image checkpoint for 2000 samples
    # ... and its start sigma follows the VD network's spread: the VD checkpoint is made too
    assert run_seconds(runs[("l2", 2000)], 100.0, cost, 50.0) == 3000.0 + 50.0 + 400.0 + 1000.0
    assert run_seconds(runs[("vd", 2000)], 100.0, cost, 50.0) == 3000.0 + 50.0 + 1000.0
    assert run_seconds(next(s for s in runs.values() if s.method == "none"), 100.0, cost, 50.0) == 3000.0


def test_the_long_runs_pages_wall_time_table_is_what_its_command_prints():
    """docs/long-runs.md's estimate table comes from the command printed above it, with the measured numbers."""
    import ast
    import re

    from vdtutorial.experiments.estimate import wall_time_table

    page = (Path(__file__).resolve().parents[1] / "docs" / "long-runs.md").read_text()
    call = re.search(r"print\(wall_time_table\(([^)]*)\)\)", page)
    assert call, "docs/long-runs.md no longer shows the estimate's command"
    args = ast.literal_eval(f"({call.group(1)},)")
    assert wall_time_table(*args) in page


def test_stored_rows_round_floats_to_what_the_csv_gives_back(tmp_path):
    """Floats are stored to 8 significant digits (runner.rows): at most 5e-8 relative, under the regeneration
    tests' 1e-6; counts, text and blanks unchanged; rounding twice is rounding once; and the rows the grid hands
    an experiment are what its CSV reads back, so a summary derived from either is the same."""
    from vdtutorial.runner.grid import _result
    from vdtutorial.runner.rows import SIGNIFICANT_DIGITS, stored_rows, stored_value, write_csv

    rng = np.random.default_rng(0)
    values = [float(v) for v in rng.standard_normal(200) * 10.0 ** rng.integers(-12, 12, 200)]
    rows = [{"label": "VD", "seed": i, "mean_kl": v, "entropy": -v, "episode": None} for i, v in enumerate(values)]
    stored = stored_rows(rows)
    assert SIGNIFICANT_DIGITS == 8
    for row, kept in zip(rows, stored):
        assert math.isclose(kept["mean_kl"], row["mean_kl"], rel_tol=5e-8) and kept["seed"] == row["seed"]
        assert (kept["label"], kept["episode"]) == ("VD", None) and stored_value(kept["mean_kl"]) == kept["mean_kl"]
    assert stored_value(0.123456789) == 0.12345679 and stored_value(7) == 7 and isinstance(stored_value(7), int)
    path = write_csv(tmp_path / "rows.csv.gz", rows)
    assert read_rows(path) == stored

    class _Job:
        def tags(self):
            return {"label": "VD"}

        def summary(self, rows):
            return ""

    assert _result(_Job(), [{k: v for k, v in r.items() if k != "label"} for r in rows], 1.0)["rows"] == stored


def test_timing_columns_are_stored_to_three_digits_and_nothing_else_is():
    """The seconds a TRPO row records (trpo.TIMING_COLUMNS, the ones the regeneration tests leave out) keep 3
    significant digits when a row is stored; every other float of the row keeps 8."""
    from vdtutorial.policy import make_policy
    from vdtutorial.rollout import make_vec_env
    from vdtutorial.runner.rows import TIMING_DIGITS, stored_rows, stored_value
    from vdtutorial.trpo import TIMING_COLUMNS, TRPO

    torch.manual_seed(0)
    env = make_vec_env("Pendulum-v1", 2)
    policy = make_policy(env.single_observation_space, 1, kind="mlp", scene_hidden=(8,))
    algo = TRPO(policy, env, TRPOConfig(steps_per_iter=400), seed=0)  # an episode ends: a mean return
    row = algo.iterate()
    env.close()
    row.update({column: 98765.4321 for column in TIMING_COLUMNS})
    stored = stored_rows([row])[0]
    assert TIMING_DIGITS == 3
    for key, value in row.items():
        expected = 98800.0 if key in TIMING_COLUMNS else stored_value(value)
        assert stored[key] == expected, key
    assert stored["mean_kl"] == float(f"{row['mean_kl']:.8g}")
