"""Image pre-training stopped on the held-out loss against the fixed epochs (experiments.pretrain_stop): the
settings it compares, its grid and its comparison (the grid itself is a long image run, not run here)."""
from pathlib import Path

import pytest

from vdtutorial.experiments import pretrain_stop as ps
from vdtutorial.pretrain import default_config


@pytest.mark.parametrize("reg", ["vd", "l2"])
def test_the_stopped_config_keeps_the_fixed_runs_warm_up_in_epochs(reg):
    fixed, stopped = default_config(reg, "rgbd"), ps.stop_config(reg)
    assert stopped.patience is not None and stopped.epochs > fixed.epochs
    assert stopped.beta_warmup * stopped.epochs == pytest.approx(fixed.beta_warmup * fixed.epochs)
    changed = {k for k in vars(fixed) if getattr(fixed, k) != getattr(stopped, k)}
    assert changed == {"epochs", "beta_warmup", "patience"}


def test_the_grid_scores_every_checkpoint_before_rl_and_runs_rl_from_each():
    jobs = ps.jobs((0, 1), Path("/tmp/out"), Path("/tmp/out/runs"))
    pre, rl = jobs[:8], jobs[8:]
    assert all(isinstance(job, ps.PreRLJob) for job in pre) and len(rl) == 8
    assert {(job.kind, job.reg, job.seed) for job in pre} == {(j.kind, j.spec.method, j.spec.seed) for j in rl}
    assert len({job.state_path for job in jobs}) == len(jobs)  # no two jobs share a state file
    stopped = [job for job in rl if job.kind == ps.STOPPED]
    assert all(job.pretrain_config.patience == ps.stop_config(job.spec.method).patience for job in stopped)
    assert all(job.spec.total_steps == ps.rl_steps() for job in rl)


def test_the_comparison_is_stopped_minus_fixed_per_method():
    rows = []
    for kind, shift in ((ps.FIXED, 0.0), (ps.STOPPED, 2.0)):
        for reg in ("vd", "l2"):
            for seed in (0, 1, 2):
                rows.append({"kind": kind, "method": reg, "seed": seed, "stage": "pre-RL", "epochs_run": 40 + 10 * shift,
                             "val_mse": 0.02, "successes": 10 + shift + seed})
                rows += [{"kind": kind, "method": reg, "seed": seed, "stage": "RL", "successes": 30 + shift + i}
                         for i in range(3)]
    comparison = ps.compare(rows, (0, 1, 2))
    assert [c["measure"].split()[0] for c in comparison[:4]] == ["epochs", "held-out", "successes", "successes"]
    epochs, _, pre_rl, rl = comparison[:4]
    assert epochs["method"] == "vd" and epochs["estimate"] == pytest.approx(20.0)
    assert pre_rl["stopped"] == [12.0, 13.0, 14.0] and pre_rl["estimate"] == pytest.approx(2.0)
    assert rl["stopped"] == [33.0] * 3 and rl["fixed"] == [31.0] * 3
