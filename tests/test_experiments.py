"""Tests of vdtutorial.experiments: tiny real runs of each method (seeded, no writes to data/), and the
numbers the figures and Table I report, on hand-made inputs."""

import csv
import importlib.util
import json
import math
import os
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import replace

import numpy as np
import pytest
import torch

from vdtutorial.demos import Demos, demo_path, generate_demos
from vdtutorial.experiments import (
    KL_WEIGHTINGS,
    METHOD_LABELS,
    TABLE1,
    Curve,
    RunSpec,
    curves_from_rows,
    expert_reference,
    finetune,
    format_table1,
    mean_band,
    moving_average,
    pretrained_policy,
    read_rows,
    results_file,
    run_experiment,
    seeds_with_trend,
    sparsity_trends,
    steps_to_reach,
    table1,
    table_means,
    vd_reaches_l2_final,
)
from vdtutorial.experiments.checkpoints import checkpoint_path
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner import backends
from vdtutorial.runner.compressed import load_compressed
from vdtutorial.settings import QUICK_ENV
from vdtutorial.trpo import TIMING_COLUMNS
from vdtutorial.vd import svdo_layers

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

#: A shipped data set (read only) and budgets that keep each run to about a second.
DEMOS = demo_path("reach", 2000, 0.5, 0)
TINY = PretrainConfig(epochs=1)
STEPS = 400  # two TRPO iterations of 200 steps


def _tiny_run(method, tmp_path, seed=0, name="run"):
    return finetune(
        method,
        "reach",
        DEMOS,
        seed=seed,
        total_steps=STEPS,
        csv_path=tmp_path / f"{name}.csv",
        pretrain_config=TINY,
        checkpoints_root=tmp_path,
    )


def _without_wall_time(rows):
    return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]


# ---------------------------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------------------------
def test_finetune_makes_the_folder_of_its_csv(tmp_path):
    """A run's log may go to a folder that does not exist yet (a study's first run made it crash)."""
    path = tmp_path / "not" / "yet" / "run.csv"
    _, rows = finetune("none", "reach", seed=0, total_steps=200, csv_path=path)
    assert len(read_rows(path)) == len(rows) == 1


@pytest.mark.parametrize("method", ["vd", "l2", "none"])
def test_finetune_writes_a_row_per_iteration(method, tmp_path):
    _, rows = _tiny_run(method, tmp_path)
    assert [r["env_steps"] for r in rows] == [200, 400]
    with open(tmp_path / "run.csv", newline="") as f:
        written = list(csv.DictReader(f))
    assert len(written) == 2
    assert {"iteration", "env_steps", "successes", "episodes", "mean_return", "mean_kl"} <= set(written[0])
    # every sub-environment starts a trajectory at the iteration start and it ends within 25 steps
    assert all(r["episodes"] >= 8 and math.isfinite(r["mean_return"]) for r in rows)
    meta = Demos.load(DEMOS).meta
    assert checkpoint_path(meta, method, "state", 0, root=tmp_path).exists() == (method != "none")


def test_vd_finetuning_keeps_pruned_weights_at_zero_and_trains_mu_and_sigma(tmp_path):
    policy, _ = _tiny_run("vd", tmp_path)
    start = pretrained_policy("vd", Demos.load(DEMOS), "state", 0, TINY, tmp_path).prune_()
    layers, start_layers = svdo_layers(policy), svdo_layers(start)
    assert sum(int((~layer.mask).sum()) for layer in layers) > 0
    for layer, before in zip(layers, start_layers):
        assert torch.equal(layer.mask, before.mask)
        assert torch.all(layer.weight[~layer.mask] == 0)
        assert torch.equal(layer.log_sigma2, before.log_sigma2)  # alpha is not trained in the RL phase
    for net in ("mu", "sigma"):
        changed = [
            not torch.equal(a, b) for a, b in zip(getattr(policy, net).parameters(), getattr(start, net).parameters())
        ]
        assert any(changed), f"TRPO did not train {net}"


def test_same_seed_same_run_and_another_seed_another(tmp_path):
    _, first = _tiny_run("l2", tmp_path, seed=3, name="a")  # pre-trains and saves the checkpoint
    _, again = _tiny_run("l2", tmp_path, seed=3, name="b")  # reuses it
    _, other = _tiny_run("l2", tmp_path, seed=4, name="c")
    assert _without_wall_time(first) == _without_wall_time(again)
    assert _without_wall_time(first) != _without_wall_time(other)


def test_stale_checkpoint_is_regenerated_with_one_plain_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(QUICK_ENV, "1")  # quick mode looks under tmp_path only (full mode tries the shipped file first)
    demos = Demos.load(DEMOS)
    pretrained_policy("l2", demos, "state", 0, TINY, tmp_path)
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an expected skip is a line of output, not a warning
        policy = pretrained_policy("l2", demos, "state", 0, PretrainConfig(epochs=2), tmp_path)
    assert policy.pretrain_info["config"]["epochs"] == 2
    said = capsys.readouterr().out.splitlines()
    assert len(said) == 1 and f"epochs={TINY.epochs}, expected 2" in said[0] and "pre-training again" in said[0]
    reused = pretrained_policy("l2", demos, "state", 0, PretrainConfig(epochs=2), tmp_path)
    assert reused.pretrain_info["config"]["epochs"] == 2 and capsys.readouterr().out == ""


def test_l2s_coefficient_does_not_make_another_vd_network_for_l2s_spread(tmp_path):
    """L2 starting from VD's spread follows the VD network cloned with the same settings; its own coefficient is
    not one of them, so two L2 coefficients share one VD checkpoint (free_choices' L2 rows)."""
    demos = Demos.load(DEMOS)
    pretrained_policy("l2", demos, "state", 0, replace(TINY, initial_sigma="spread"), tmp_path)
    vd_file = checkpoint_path(demos.meta, "vd", "state", 0, root=tmp_path)
    made = vd_file.stat().st_mtime_ns
    pretrained_policy("l2", demos, "state", 0, replace(TINY, l2=1e-3, initial_sigma="spread"), tmp_path)
    assert vd_file.stat().st_mtime_ns == made


def test_results_do_not_depend_on_the_number_of_workers_or_the_backend(tmp_path):
    """Local: this process and 2 worker processes; Ray: a local Ray with 2 CPUs, one task per run."""
    specs = [RunSpec("l2", "reach", 2000, 0.5, seed, "state", STEPS, "L2") for seed in (0, 1)]
    specs.append(RunSpec("none", "reach", None, None, 0, "state", STEPS, "none"))
    results = {}
    backends = (("local", 1), ("local", 2)) + ((("ray", 2),) if importlib.util.find_spec("ray") else ())
    for backend, workers in backends:
        out = tmp_path / f"{backend}{workers}"
        results[backend, workers] = run_experiment(
            "tiny",
            specs,
            "tiny",
            out,
            workers,
            checkpoints_root=out,
            pretrain_config=TINY,
            window=2,
            command="test",
            backend=backend,
            progress=False,
        )
        assert {p.name for p in out.iterdir()} >= {"tiny.csv.gz", "tiny.png", "tiny.json", "runs", "checkpoints"}
        assert len(list((out / "runs").glob("*.csv"))) == 3 and len(list((out / "runs").glob("*.pt"))) == 3
    reference = _without_wall_time(results["local", 1].rows)
    assert _without_wall_time(results["local", 2].rows) == reference
    record = json.loads((tmp_path / "local2" / "tiny.json").read_text())
    assert record["command"] == "test" and len(record["runs"]) == 3 and record["pretrain_config"]["epochs"] == 1
    if ("ray", 2) in results:  # Ray is an extra (cluster, test): Colab's leg goes without it
        assert _without_wall_time(results["ray", 2].rows) == reference
        assert json.loads((tmp_path / "ray2" / "tiny.json").read_text())["backend"] == "ray"
    # the combined CSV reads back into the same curves
    rows = read_rows(results_file(tmp_path / "local2", "tiny"))
    again = curves_from_rows(rows, "successes", window=2)["L2"]
    assert np.allclose(again.mean, results["local", 2].curves["L2"].mean)


class _FlakyRay:
    """Stands in for the ray module: ``init`` times out the way Ray's does on a busy machine, ``failures`` times."""

    def __init__(self, failures):
        self.failures, self.calls = failures, []

    def init(self, **kwargs):
        self.calls.append("init")
        if self.calls.count("init") <= self.failures:
            raise Exception("The current node timed out during startup.")  # noqa: TRY002 -- what Ray raises

    def shutdown(self):
        self.calls.append("shutdown")


def test_a_local_ray_that_times_out_at_startup_is_tried_again():
    ray = _FlakyRay(failures=2)
    backends._start_local_ray(ray, 2, {})
    assert ray.calls == ["init", "shutdown", "init", "shutdown", "init"]
    ray = _FlakyRay(failures=backends.LOCAL_RAY_ATTEMPTS)
    with pytest.raises(RuntimeError, match=r"in 3 tries \(The current node timed out.*65983.*local backend"):
        backends._start_local_ray(ray, 2, {})
    assert ray.calls.count("init") == backends.LOCAL_RAY_ATTEMPTS


def test_an_unreachable_ray_address_fails_within_30_s_in_one_line(tmp_path):
    """An ``--address`` nothing answers at: one ``error:`` line and exit code 2 within 30 s (Ray alone kept
    retrying the connection for minutes)."""
    pytest.importorskip("ray")
    start = time.monotonic()
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "vdtutorial",
            "experiment",
            "fig4",
            "--seeds",
            "0",
            "--steps",
            "400",
            "--backend",
            "ray",
            "--address",
            "127.0.0.1:1",
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, QUICK_ENV: "1"},
    )
    assert time.monotonic() - start < 30
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1].startswith("error: no Ray cluster answers at 127.0.0.1:1")


def test_a_ray_address_that_never_answers_is_refused_after_the_timeout(monkeypatch):
    def silent(address, timeout):
        raise TimeoutError("timed out")

    monkeypatch.setattr(backends.socket, "create_connection", silent)
    with pytest.raises(ConnectionError, match=r"no Ray cluster answers at ray://10.0.0.1:10001 \(timed out\)"):
        backends._check_reachable("ray://10.0.0.1:10001")
    backends._check_reachable("auto")  # an address Ray resolves itself is left to Ray


def _pool_job(job):
    """A job for the local pool: ("sleep", seconds), ("fail", _) raises, ("die", _) kills its own worker."""
    kind, seconds = job
    if kind == "fail":
        raise ValueError("this run failed")
    yield {"env_steps": 0}
    if kind == "die":
        time.sleep(1)  # let the worker's "started" message reach the parent first
        os.kill(os.getpid(), signal.SIGKILL)  # what the system's out-of-memory killer does
    time.sleep(seconds)
    return seconds


@pytest.mark.parametrize("kind, error", [("fail", "this run failed"), ("die", "died without an error")])
def test_a_failed_or_killed_worker_stops_the_pool_at_once(kind, error):
    """A run that fails, or whose worker is killed, stops the grid while the other run is still going (the
    pool used to report a failure only after every other run had ended, and to wait for ever for a killed one)."""
    start = time.monotonic()
    with pytest.raises((ValueError, RuntimeError), match=error):
        backends.run_jobs(_pool_job, [("sleep", 120), (kind, 0)], workers=2)
    assert time.monotonic() - start < 60


def test_expert_reference_counts_like_a_trpo_iteration():
    rows = expert_reference("grasp", seed=0, episodes=1)
    row = rows[0]
    assert row["episodes"] >= 8 and 0 < row["successes"] <= row["episodes"]
    # sparse reward: -1 per step, +25 success, -25 collision; a grasp of a few steps returns ~20
    assert 10 < row["mean_return"] < 25


# ---------------------------------------------------------------------------------------------
# Curves and summaries on hand-made numbers
# ---------------------------------------------------------------------------------------------
def test_trailing_moving_average():
    assert np.allclose(moving_average([1, 2, 3, 4], 2), [1, 1.5, 2.5, 3.5])
    assert np.allclose(moving_average([[1, 2, 3], [3, 3, 3]], 5), [[1, 1.5, 2], [3, 3, 3]])
    assert np.allclose(moving_average([4, 0, 2], 1), [4, 0, 2])


def test_t_band_on_a_hand_example():
    mean, low, high = mean_band([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    # sd = 1, n = 3: half width t_{0.975, 2} / sqrt(3) = 4.3027 / 1.7321 = 2.4841
    assert np.allclose(mean, [2.0, 0.0])
    assert np.allclose(high - mean, [2.4841, 0.0], atol=1e-4) and np.allclose(mean - low, high - mean)
    mean, low, high = mean_band([[5.0]])
    assert mean[0] == 5.0 and np.isnan(low[0]) and np.isnan(high[0])


def test_steps_to_reach_on_hand_made_curves():
    steps = [200, 400, 600, 800, 1000]
    assert steps_to_reach(steps, [0, 1, 3, 2, 5], 3) == 600
    assert steps_to_reach(steps, [0, 1, 3, 2, 5], 0) == 200
    assert steps_to_reach(steps, [0, 1, 3, 2, 5], 5.5) is None


def _curve(method, values):
    values = np.asarray(values, dtype=float)
    return Curve(METHOD_LABELS[method], method, 200.0 * np.arange(1, len(values) + 1), values, values, values, 3)


def test_vd_reaches_l2_final_on_hand_made_curves():
    curves = {c.label: c for c in (_curve("vd", [0, 2, 4, 6, 6]), _curve("l2", [0, 1, 2, 3, 4]))}
    summary = vd_reaches_l2_final(curves)
    assert summary["l2_final_level"] == 4 and summary["steps"] == 600 and summary["fraction_of_budget"] == 0.6
    curves = {c.label: c for c in (_curve("vd", [0, 1, 1, 1, 1]), _curve("l2", [0, 1, 2, 3, 4]))}
    assert vd_reaches_l2_final(curves)["steps"] is None and "never" in vd_reaches_l2_final(curves)["text"]


def test_vd_reaches_l2_final_says_what_each_reading_of_the_paper_gives():
    # "around 1.25e5 of 3e5 steps" is 42% of the budget, "less than one quarter" 25%: at 40% only the first is met
    curves = {c.label: c for c in (_curve("vd", [0, 4, 4, 4, 4]), _curve("l2", [0, 1, 2, 3, 4]))}
    text = vd_reaches_l2_final(curves)["text"]
    assert "40% of the budget" in text
    assert "'around 1.25e5 of 3e5 steps' (42%): met" in text and "'less than one quarter' (25%): not met" in text


def test_curves_from_rows_smooths_each_seed_then_averages():
    rows = [
        {"label": "VD", "method": "vd", "seed": s, "iteration": i, "env_steps": 200 * (i + 1), "successes": v}
        for s, values in ((0, [0, 2, 4]), (1, [2, 2, 2]))
        for i, v in enumerate(values)
    ]
    rows += [
        {"label": "IK expert", "method": "expert", "seed": s, "episode": 0, "successes": v}
        for s, v in ((0, 70), (1, 72))
    ]
    curves = curves_from_rows(rows, "successes", window=2)
    # seed 0 smoothed: [0, 1, 3]; seed 1: [2, 2, 2]; mean [1, 1.5, 2.5]
    assert np.allclose(curves["VD"].mean, [1, 1.5, 2.5]) and np.allclose(curves["VD"].steps, [200, 400, 600])
    assert curves["IK expert"].mean[0] == 71 and curves["IK expert"].steps.size == 0


# ---------------------------------------------------------------------------------------------
# Table I
# ---------------------------------------------------------------------------------------------
def _table_rows(values, seed=0):
    return [
        {
            "experiment": row,
            "task": task,
            "samples": n,
            "noise": s,
            "neuron_fraction": v,
            "seed": seed,
            "neuron_fraction_paper": paper,
            "weight_fraction": 0.5,
        }
        for (row, task, n, s, paper), v in zip(TABLE1, values)
    ]


def test_table1_trends_on_hand_made_numbers():
    paper = [row[-1] for row in TABLE1]
    rows = _table_rows(paper)
    assert sparsity_trends(rows) == {"more demonstrations -> sparser": True, "less noise -> sparser": True}
    # 4000 demonstrations sparser than 8000; Sigma 0.25 less sparse than 0.5
    rows = _table_rows([0.60, 0.65, 0.40, 0.55, 0.70, 0.5])
    assert sparsity_trends(rows) == {"more demonstrations -> sparser": False, "less noise -> sparser": False}
    text = format_table1(rows)
    assert "does NOT hold" in text and "0.677" in text and "(1 seed)" in text


def test_table1_means_intervals_and_trends_over_seeds():
    """Seed 0 has the paper's ordering, seed 1 the reverse: the means (0.5 everywhere but grasping) then
    hold neither trend strictly, each trend holds in 1 of 2 seeds, and the interval is the t-interval."""
    paper = [row[-1] for row in TABLE1]
    reverse = [1 - v for v in paper[:5]] + [paper[5]]
    rows = _table_rows(paper, 0) + _table_rows(reverse, 1)
    means = table_means(rows)
    assert [m["seeds"] for m in means] == [2] * 6
    first = means[0]  # 0.677 and 0.323: mean 0.5, half-width t_{0.975,1} * sd / sqrt(2) = 12.706 * 0.177
    assert first["neuron_fraction"] == pytest.approx(0.5)
    assert first["high"] - first["neuron_fraction"] == pytest.approx(12.7062 * 0.177, rel=1e-4)
    assert seeds_with_trend(rows) == {"more demonstrations -> sparser": (1, 2), "less noise -> sparser": (1, 2)}
    assert "in 1 of 2 seeds" in format_table1(rows)


def test_cli_kl_weightings_are_the_library_ones():
    from vdtutorial.__main__ import build_parser

    action = next(
        a
        for a in build_parser()._subparsers._group_actions[0].choices["experiment"]._actions
        if a.dest == "kl_weighting"
    )
    assert tuple(action.choices) == tuple(KL_WEIGHTINGS) and KL_WEIGHTINGS["per-set"] is None
    assert KL_WEIGHTINGS["fixed"] == 7200  # 8000 demonstrations, 10% held out


def test_table1_fixed_weighting_pretrains_its_own_checkpoints(tmp_path):
    """kl_weighting="fixed": every data set is pre-trained with kl_divisor = 7200, into checkpoints of
    their own name (never the per-set ones); a row per data set and seed."""
    rows = table1(seeds=(0, 1), kl_weighting="fixed", out=tmp_path, workers=1, pretrain_config=PretrainConfig(epochs=1))
    assert len(rows) == 12 and {r["kl_divisor"] for r in rows} == {7200} and {r["seed"] for r in rows} == {0, 1}
    made = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert len(made) == 12 and all(name.endswith(("_kl7200.pt")) for name in made)
    text = (tmp_path / "table1_fixed.txt").read_text()
    assert "KL weighting: fixed (kl_divisor=7200)" in text and "--kl-weighting fixed" in text
    assert all(0 <= r["neuron_fraction"] <= 1 for r in read_rows(tmp_path / "table1_fixed.csv"))
    with pytest.raises(ValueError, match="kl_weighting"):
        table1(kl_weighting="8000", out=tmp_path)


@pytest.mark.parametrize("folder", ["table1", "table1_rgbd"])
def test_shipped_table1_rows_are_the_shipped_checkpoints(folder):
    """Every shipped per-set Table I row whose checkpoint is shipped too (all state rows; the image table's
    8000-sample, Sigma = 0.5 row, whose other image checkpoints are too big to ship) is what
    ``sparsity_report`` measures on that checkpoint now."""
    from vdtutorial.experiments.checkpoints import load_checkpoint
    from vdtutorial.runner.rows import stored_value
    from vdtutorial.settings import data_dir
    from vdtutorial.analysis.sparsity import sparsity_report

    rows = read_rows(data_dir() / "results" / folder / "table1_per-set.csv")
    assert {r["experiment"] for r in rows} == {row[0] for row in TABLE1}
    checked = 0
    for r in rows:
        meta = {"task": r["task"], "samples": int(r["samples"]), "noise": float(r["noise"])}
        path = checkpoint_path(meta, "vd", r["obs_mode"], int(r["seed"]))
        if not path.exists():
            continue
        report = sparsity_report(load_checkpoint(path).mu)
        # as the CSV stores a float (vdtutorial.runner.rows: 8 significant digits)
        assert float(r["neuron_fraction"]) == stored_value(report.neuron_fraction), path.name
        assert float(r["weight_fraction"]) == stored_value(report.weight_fraction), path.name
        checked += 1
    assert checked == (len(rows) if folder == "table1" else 1)


def test_quick_mode_never_replaces_shipped_checkpoints(monkeypatch, tmp_path):
    """With no checkpoints_root, quick mode looks up and saves checkpoints under runs/quick, not data/."""
    from vdtutorial.experiments import pipeline

    monkeypatch.setenv("VDTUTORIAL_RUNS", str(tmp_path))
    monkeypatch.setattr(pipeline, "budget", lambda full, quick: quick)
    demos = generate_demos("reach", 40, 0.3, seed=1, progress=False)
    pipeline.pretrained_policy("l2", demos, "state", 0, PretrainConfig(reg="l2", epochs=1))
    saved = list(tmp_path.rglob("*.pt"))
    assert [p.name for p in saved] == ["reach_n40_sigma0.3_demos1_l2_state_seed0.pt"]  # demonstrations of seed 1


def test_files_written_before_kl_divisor_was_renamed_still_load_and_merge():
    """``PretrainConfig.kl_samples`` became ``kl_divisor`` (it divides the KL; it counts nothing). The shipped
    checkpoints still record the old name: they load with the new one, and a results record that holds the old
    name is the same experiment as one with the new."""
    from vdtutorial.experiments.checkpoints import load_checkpoint
    from vdtutorial.experiments.results import with_defaults

    path = checkpoint_path(Demos.load(demo_path("reach", 8000, 0.5, 0)).meta, "vd", "state", 0)
    assert "kl_samples" in load_compressed(path)["meta"]["config"]  # as shipped
    config = load_checkpoint(path, kl_divisor=None).pretrain_info["config"]
    assert "kl_samples" not in config and PretrainConfig(**config).kl_divisor is None
    old, new = {"kl_samples": 7200, "epochs": 40}, {"kl_divisor": 7200, "epochs": 40}
    names = set(old) | set(new)
    assert with_defaults("pretrain_config", old, names) == with_defaults("pretrain_config", new, names)
    assert with_defaults("pretrain_config", old, names) != with_defaults(
        "pretrain_config", {**new, "kl_divisor": 1}, names
    )
