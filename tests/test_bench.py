"""The fine-tuning benchmark: real TRPO iterations on the shipped pruned VD policy, timed."""

import pytest

from vdtutorial.cli.bench import bench_finetune

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only


def test_bench_finetune_times_both_fisher_products_and_the_subsample(capsys):
    rows = bench_finetune(iterations=1, profile=True)
    assert [(r["obs_mode"], r["fisher"], r["fvp_subsample"]) for r in rows] == [
        (obs, fisher, f)
        for obs in ("state", "rgbd")
        for fisher, f in (("double_backward", 1.0), ("gauss_newton", 1.0), ("gauss_newton", 0.1))
    ]
    for row in rows:
        assert row["steps_per_s"] > 0 and row["steps_per_cpu_s"] > 0 and 0 <= row["mean_kl"] <= 0.01 + 1e-7
        assert row["policy"].startswith("shipped")
    assert any(row["step_fraction"] > 0 for row in rows)  # the updates did move the policy
    rgbd = {(r["fisher"], r["fvp_subsample"]): r for r in rows if r["obs_mode"] == "rgbd"}
    # the same exact Fisher on the whole batch, several times cheaper in Gauss-Newton form
    assert rgbd["gauss_newton", 1.0]["update_s"] < 0.6 * rgbd["double_backward", 1.0]["update_s"]
    out = capsys.readouterr().out
    assert "Gauss-Newton / double backward" in out
    parts = ("gradient", "fisher_setup", "cg_products", "line_search", "baseline")
    for row in rows:  # the update's parts, each timed, add up to less than the iteration's CPU time
        assert tuple(row["split_cpu_s"]) == parts and all(t >= 0 for t in row["split_cpu_s"].values())
        assert 0 < sum(row["split_cpu_s"].values()) < 200 / row["steps_per_cpu_s"]
        assert row["split_cpu_s"]["cg_products"] > 0
    assert out.count("update split, CPU s per iteration") == 2
    # the profile of the rgbd whole-batch case: torch's operators, then the Python functions
    profile = out[out.index("profile:") :]
    assert "aten::" in profile and "getCameraImage" in profile
