"""The fine-tuning benchmark: real TRPO iterations on the shipped pruned VD policy, timed."""
from vdtutorial.bench import bench_finetune


def test_bench_finetune_times_both_fisher_settings(capsys):
    rows = bench_finetune(iterations=1)
    assert [(r["obs_mode"], r["fvp_subsample"]) for r in rows] == [
        ("state", 1.0), ("state", 0.1), ("rgbd", 1.0), ("rgbd", 0.1)]
    for row in rows:
        assert row["steps_per_s"] > 0 and 0 <= row["mean_kl"] <= 0.01 + 1e-7
        assert row["policy"].startswith("shipped")
    assert any(row["step_fraction"] > 0 for row in rows)  # the updates did move the policy
    rgbd = {r["fvp_subsample"]: r for r in rows if r["obs_mode"] == "rgbd"}
    # 20 instead of 200 samples in the 11 Fisher-vector products: the update is several times cheaper
    assert rgbd[0.1]["update_s"] < 0.6 * rgbd[1.0]["update_s"]
    assert "rgbd" in capsys.readouterr().out
