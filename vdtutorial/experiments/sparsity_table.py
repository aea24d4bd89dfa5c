"""Table I: neuron sparsification of the VD-pre-trained policies beside the paper's ratios."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from vdtutorial.demos import SHIPPED_NOISE, Demos, demo_path
from vdtutorial.experiments.backends import run_jobs
from vdtutorial.experiments.results import default_out, experiment_command
from vdtutorial.experiments.rows import write_csv
from vdtutorial.experiments.runs import pretrained_policy
from vdtutorial.pretrain import PretrainConfig, default_config
from vdtutorial.vd import sparsity_report

#: Table I: (row, task, demonstrations, Sigma, the paper's neuron sparsification ratio).
TABLE1 = (
    ("8000 demonstrations; Sigma = 0.5", "reach", 8000, 0.5, 0.677),
    ("4000 demonstrations; Sigma = 0.5", "reach", 4000, 0.5, 0.526),
    ("2000 demonstrations; Sigma = 0.5", "reach", 2000, 0.5, 0.359),
    ("8000 demonstrations; Sigma = 0.25", "reach", 8000, 0.25, 0.685),
    ("8000 demonstrations; Sigma = 0.05", "reach", 8000, 0.05, 0.766),
    ("Grasping", "grasp", 8000, SHIPPED_NOISE["grasp"], 0.693),
)


@dataclass(frozen=True)
class _SparsityJob:
    demos: Path
    obs_mode: str
    seed: int
    checkpoints_root: Path | None
    pretrain_config: PretrainConfig | None


def _sparsity_job(job: _SparsityJob) -> dict:
    demos = Demos.load(job.demos)
    policy = pretrained_policy("vd", demos, job.obs_mode, job.seed, job.pretrain_config, job.checkpoints_root)
    report = sparsity_report(policy.mu)
    return {"neuron_fraction": report.neuron_fraction, "weight_fraction": report.weight_fraction}


def sparsity_trends(rows: list[dict], column: str = "neuron_fraction") -> dict[str, bool]:
    """The two trends of Table I, checked on ``column`` of the reaching rows: sparsity grows strictly
    with the number of demonstrations (2000 < 4000 < 8000 at Sigma = 0.5) and as the expert noise falls
    (Sigma 0.5 < 0.25 < 0.05 at 8000 demonstrations)."""
    value = {(r["samples"], r["noise"]): r[column] for r in rows if r["task"] == "reach"}
    increasing = (lambda keys: all(value[a] < value[b] for a, b in zip(keys, keys[1:])))
    return {"more demonstrations -> sparser": increasing([(2000, 0.5), (4000, 0.5), (8000, 0.5)]),
            "less noise -> sparser": increasing([(8000, 0.5), (8000, 0.25), (8000, 0.05)])}


def format_table1(rows: list[dict]) -> str:
    """Table I as text: measured neuron and weight sparsity beside the paper's, then the trend checks."""
    lines = [f"{'experiment':<36}{'neurons':>9}{'paper':>8}{'weights':>9}"]
    lines += [f"{r['experiment']:<36}{r['neuron_fraction']:>9.3f}{r['neuron_fraction_paper']:>8.3f}"
              f"{r['weight_fraction']:>9.3f}" for r in rows]
    measured, paper = sparsity_trends(rows), sparsity_trends(rows, "neuron_fraction_paper")
    lines += [f"trend '{k}': measured {'holds' if measured[k] else 'does NOT hold'} "
              f"(paper: {'holds' if paper[k] else 'does not hold'})" for k in measured]
    return "\n".join(lines)


def table1(obs_mode: str = "state", seed: int = 0, out=None, workers: int = 2, demos_root: Path | None = None,
           checkpoints_root: Path | None = None, pretrain_config: PretrainConfig | None = None, *,
           backend: str = "local", address: str | None = None) -> list[dict]:
    """Table I: neuron sparsification of the VD-pre-trained mu on each of the five reaching data sets and
    the grasping set, beside the paper's ratios, plus the fraction of weights pruned. Reuses (or makes)
    the same checkpoints as the fine-tuning runs. Writes ``table1.csv`` and ``table1.txt`` into ``out``
    (default ``runs/table1``; quick mode: ``runs/quick/table1``), prints the table, and returns the rows.
    Checkpoints that must be made (the shipped ones do not match) go under ``checkpoints_root``
    (default ``out``). ``backend``, ``address``: as for the figures (:mod:`~vdtutorial.experiments.backends`)."""
    out = Path(out) if out is not None else default_out("table1")
    checkpoints_root = Path(checkpoints_root if checkpoints_root is not None else out).resolve()
    jobs = [_SparsityJob(demo_path(task, samples, noise, 0, root=demos_root).resolve(), obs_mode, seed,
                         checkpoints_root, pretrain_config) for _, task, samples, noise, _ in TABLE1]
    measured = run_jobs(_sparsity_job, jobs, workers, backend, address)
    rows = [{"experiment": row, "task": task, "samples": samples, "noise": noise, "obs_mode": obs_mode, "seed": seed,
             **m, "neuron_fraction_paper": paper} for (row, task, samples, noise, paper), m in zip(TABLE1, measured)]
    write_csv(out / "table1.csv", rows)
    text = format_table1(rows)
    command = experiment_command("table1", obs=obs_mode, seeds=(seed,), workers=workers, out=out)
    (out / "table1.txt").write_text(f"{text}\n\ncommand: {command}\npretrain config: "
                                    f"{asdict(pretrain_config or default_config('vd', obs_mode))}\n")
    print(text)
    return rows

