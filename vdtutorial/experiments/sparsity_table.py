"""Table I: neuron sparsification of the VD-pre-trained policies beside the paper's ratios, over seeds
and under two weightings of the KL term.

Why two weightings: eq. 3 is the sum over the N samples of D of the log-likelihood minus one KL term,
so per sample the KL weighs 1/N -- a small data set is pushed harder towards the prior, and so pruned
more. Table I reports the opposite trend (more data, sparser). The paper does not say how its loss
was normalised, so the table is measured both ways: ``per-set`` (1/N with each set's own training-split
size, eq. 3 as written, ``PretrainConfig.kl_divisor=None``) and ``fixed`` (1/N_8000 for every set, the
8000-sample set's nominal training split, so that the rows differ only by their data).

Taught in chapter 05 and appendix A1.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from vdtutorial.analysis.sparsity import sparsity_report
from vdtutorial.demos import SHIPPED_NOISE, Demos, demo_path
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.curves import mean_band
from vdtutorial.experiments.results import default_out, experiment_command
from vdtutorial.experiments.pipeline import pretrained_policy
from vdtutorial.pretrain import PAPER_SIGMA_OPTION, PretrainConfig
from vdtutorial.runner.backends import run_jobs
from vdtutorial.runner.rows import stored_rows, write_csv

#: Table I: (row, task, demonstrations, Sigma, the paper's neuron sparsification ratio).
TABLE1 = (
    ("8000 demonstrations; Sigma = 0.5", "reach", 8000, 0.5, 0.677),
    ("4000 demonstrations; Sigma = 0.5", "reach", 4000, 0.5, 0.526),
    ("2000 demonstrations; Sigma = 0.5", "reach", 2000, 0.5, 0.359),
    ("8000 demonstrations; Sigma = 0.25", "reach", 8000, 0.25, 0.685),
    ("8000 demonstrations; Sigma = 0.05", "reach", 8000, 0.05, 0.766),
    ("Grasping", "grasp", 8000, SHIPPED_NOISE["grasp"], 0.693),
)


#: The KL weightings of Table I: the ``PretrainConfig.kl_divisor`` each one sets
#: (module docstring, "Why two weightings").
#: "fixed" divides by the 8000-sample set's nominal training split, 8000 x (1 - 0.1 held out).
KL_WEIGHTINGS = {"per-set": None, "fixed": round(8000 * (1 - PretrainConfig.val_fraction))}


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


def table_means(rows: list[dict], column: str = "neuron_fraction") -> list[dict]:
    """One row per experiment of Table I: the mean of ``column`` over seeds with its 95% Student-t
    interval (NaN bounds with one seed), and the paper's ratio."""
    out = []
    for experiment, task, samples, noise, paper in TABLE1:
        values = [r[column] for r in rows if r["experiment"] == experiment]
        if not values:
            continue
        mean, low, high = (float(x[0]) for x in mean_band([[v] for v in values]))
        out.append(
            {
                "experiment": experiment,
                "task": task,
                "samples": samples,
                "noise": noise,
                column: mean,
                "low": low,
                "high": high,
                "seeds": len(values),
                "neuron_fraction_paper": paper,
            }
        )
    return out


def sparsity_trends(rows: list[dict], column: str = "neuron_fraction") -> dict[str, bool]:
    """The two trends of Table I, checked on ``column`` of the reaching rows (one row per data set, e.g.
    :func:`table_means`): sparsity grows strictly with the number of demonstrations (2000 < 4000 < 8000
    at Sigma = 0.5) and as the expert noise falls (Sigma 0.5 < 0.25 < 0.05 at 8000 demonstrations)."""
    value = {(r["samples"], r["noise"]): r[column] for r in rows if r["task"] == "reach"}

    def increasing(keys):
        return all(value[a] < value[b] for a, b in zip(keys, keys[1:]))

    return {
        "more demonstrations -> sparser": increasing([(2000, 0.5), (4000, 0.5), (8000, 0.5)]),
        "less noise -> sparser": increasing([(8000, 0.5), (8000, 0.25), (8000, 0.05)]),
    }


def seeds_with_trend(rows: list[dict]) -> dict[str, tuple[int, int]]:
    """For each trend of :func:`sparsity_trends`: (seeds in which it holds, seeds)."""
    seeds = sorted({r["seed"] for r in rows})
    held = [sparsity_trends([r for r in rows if r["seed"] == s]) for s in seeds]
    return {trend: (sum(h[trend] for h in held), len(seeds)) for trend in held[0]}


def format_table1(rows: list[dict]) -> str:
    """Table I as text: measured neuron sparsity (mean over seeds, 95% interval) and weight sparsity beside
    the paper's, then the trend checks on the means and seed by seed."""
    neurons, weights = table_means(rows), table_means(rows, "weight_fraction")
    lines = [f"{'experiment':<36}{'neurons':>9}{'95% interval':>16}{'paper':>8}{'weights':>9}"]
    for n, w in zip(neurons, weights):
        band = f"{n['low']:.3f}-{n['high']:.3f}" if math.isfinite(n["low"]) else "(1 seed)"
        lines.append(
            f"{n['experiment']:<36}{n['neuron_fraction']:>9.3f}{band:>16}{n['neuron_fraction_paper']:>8.3f}"
            f"{w['weight_fraction']:>9.3f}"
        )
    measured, paper = sparsity_trends(neurons), sparsity_trends(neurons, "neuron_fraction_paper")
    per_seed = seeds_with_trend(rows)
    lines += [
        f"trend '{k}': measured on the means {'holds' if measured[k] else 'does NOT hold'}, in "
        f"{per_seed[k][0]} of {per_seed[k][1]} seeds (paper: {'holds' if paper[k] else 'does not hold'})"
        for k in measured
    ]
    return "\n".join(lines)


def table1(
    obs_mode: str = "state",
    seeds=(0,),
    kl_weighting: str = "per-set",
    out=None,
    workers: int = 2,
    demos_root: Path | None = None,
    checkpoints_root: Path | None = None,
    pretrain_config: PretrainConfig | None = None,
    *,
    backend: str = "local",
    address: str | None = None,
) -> list[dict]:
    """Table I: neuron sparsification of the VD-pre-trained mu on each of the five reaching data sets and
    the grasping set, for each of ``seeds``, beside the paper's ratios, plus the fraction of weights
    pruned. ``kl_weighting`` ("per-set" or "fixed", :data:`KL_WEIGHTINGS`) sets ``kl_divisor`` of the
    pre-training configuration. Reuses (or makes) the same checkpoints as the fine-tuning runs (per-set
    weighting). Writes ``table1_WEIGHTING.csv`` (a row per data set and seed) and ``table1_WEIGHTING.txt``
    (:func:`format_table1`, the command, the configuration) into ``out`` (default ``runs/table1``; quick
    mode: ``runs/quick/table1``), prints the table, and returns the rows. Checkpoints that must be made
    go under ``checkpoints_root`` (default ``out``). ``backend``, ``address``: as for the figures
    (:mod:`~vdtutorial.runner.backends`)."""
    if kl_weighting not in KL_WEIGHTINGS:
        raise ValueError(f"kl_weighting must be one of {tuple(KL_WEIGHTINGS)}, got {kl_weighting!r}")
    seeds = tuple(seeds)
    out = Path(out) if out is not None else default_out("table1")
    checkpoints_root = Path(checkpoints_root if checkpoints_root is not None else out).resolve()
    # sparsity is a property of mu, which the initial sigma does not change: the checkpoints of the base setting
    config = replace(
        pretrain_config or default_config("vd", obs_mode),
        kl_divisor=KL_WEIGHTINGS[kl_weighting],
        initial_sigma=PAPER_SIGMA_OPTION,
    )
    plan = [(entry, seed) for seed in seeds for entry in TABLE1]
    jobs = [
        _SparsityJob(
            demo_path(task, samples, noise, 0, root=demos_root).resolve(), obs_mode, seed, checkpoints_root, config
        )
        for (_, task, samples, noise, _), seed in plan
    ]
    measured = run_jobs(_sparsity_job, jobs, workers, backend, address)
    rows = stored_rows(
        [
            {
                "experiment": row,
                "task": task,
                "samples": samples,
                "noise": noise,
                "obs_mode": obs_mode,
                "seed": seed,
                "kl_weighting": kl_weighting,
                "kl_divisor": config.kl_divisor,
                **m,
                "neuron_fraction_paper": paper,
            }
            for ((row, task, samples, noise, paper), seed), m in zip(plan, measured)
        ]
    )
    write_csv(out / f"table1_{kl_weighting}.csv", rows)
    text = format_table1(rows)
    command = experiment_command(
        "table1", obs=obs_mode, seeds=seeds, kl_weighting=kl_weighting, workers=workers, out=out
    )
    (out / f"table1_{kl_weighting}.txt").write_text(
        f"KL weighting: {kl_weighting} (kl_divisor={config.kl_divisor})\n{text}\n\ncommand: {command}\n"
        f"pretrain config: {asdict(config)}\n"
    )
    print(text)
    return rows
