"""The study of sigma at the start of RL (:mod:`vdtutorial.experiments.initial_sigma`): each option's score before
and during RL, in state mode on reaching, and the choice of the default by the rule written down first
in ``data/results/sigma_study/RULE.md``.

For every option and seed it runs VD, L2 and (once per distinct starting sigma) no pre-training through
:func:`vdtutorial.experiments.finetune`, the same code path as Figs. 4-7, and measures each pre-trained
policy's mean-action score before RL in TRPO's layout (8 fresh 25-step runs = one 200-step episode).
"Iteration 0" is TRPO's first iteration, whose batch is sampled from the initial policy.

Writes ``sigma_study.csv.gz`` (the TRPO rows of every run, a few columns), ``sigma_study.json`` (command,
settings, the summary per option and method with 95% t-intervals over seeds, the rule's decision) and
``sigma_study.png`` into ``out``. Run ``python -m vdtutorial.experiments.sigma_study --help``.

Taught in appendix A4.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from matplotlib.figure import Figure

import vdtutorial
from vdtutorial.experiments.initial_sigma import InitialSigma
from vdtutorial.demos import demo_path
from vdtutorial.envs import ENV_IDS
from vdtutorial.experiments import (
    METHOD_LABELS,
    NUM_ENVS,
    curves_from_rows,
    finetune,
    load_demos,
    mean_band,
    finetune_policy,
    read_rows,
    results_file,
    run_jobs,
    stored_rows,
    write_csv,
)
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.evaluation import EPISODE_STEPS, mean_action_successes
from vdtutorial.experiments.plots import draw_band, save_png
from vdtutorial.experiments.paths import recorded_path, runs_dir
from vdtutorial.methods import method as method_entry
from vdtutorial.settings import data_dir

#: Candidates of the rule: option (a) at the paper's 0.3 and at the issue's probe value 0.05, (b), (c).
OPTIONS = ("0.3", "0.05", "demos", "spread")
#: Columns of the TRPO rows kept in the combined CSV.
COLUMNS = ("option", "method", "seed", "iteration", "env_steps", "successes", "episodes", "mean_return", "entropy")
FIRST, LAST = 5, 25


@dataclass(frozen=True)
class _Run:
    method: str
    option: str
    seed: int
    steps: int
    csv_path: Path


def _run(job: _Run) -> list[dict]:
    """One run through ``finetune``. A per-run CSV left by an earlier call with at least as many iterations
    is read instead (the study can be resumed or shortened: TRPO's iterations do not depend on the
    budget, so the first k iterations of a longer run are those of a run of k iterations)."""
    done = read_rows(job.csv_path) if job.csv_path.exists() else []
    needed = job.steps // EPISODE_STEPS
    rows = done[:needed] if len(done) >= needed else _finetune(job)
    return [
        {"option": job.option, "method": job.method, "seed": job.seed, **{k: r[k] for k in COLUMNS[3:]}} for r in rows
    ]


def _finetune(job: _Run) -> list[dict]:
    cfg = replace(default_config(job.method), initial_sigma=job.option)
    demos = demo_path("reach", 8000, 0.5, 0) if method_entry(job.method).pretrains else None
    return finetune(job.method, "reach", demos, "state", job.seed, job.steps, job.csv_path, pretrain_config=cfg)[1]


def mean_action_score(reg: str, seed: int, episodes: int = 3) -> float:
    """Successes per 200-step episode of the pre-trained policy's mean action, before RL, counted as
    TRPO counts an iteration: ``NUM_ENVS`` fresh runs of ``200 / NUM_ENVS`` steps (reset seeds derived from
    (seed, k)), averaged over ``episodes`` episodes."""
    env = gym.make(ENV_IDS["reach"], obs_mode="state")
    policy = finetune_policy(reg, env, load_demos("reach"), "state", seed)
    env.close()
    return mean_action_successes(policy, "reach", seed, episodes, NUM_ENVS)["successes"]


def _mean_action_job(job: tuple[str, int]) -> dict:
    return {"method": job[0], "seed": job[1], "mean_action": mean_action_score(*job)}


def _interval(values) -> dict:
    mean, low, high = mean_band(np.asarray(values, dtype=np.float64)[:, None])
    return {"mean": float(mean[0]), "low": float(low[0]), "high": float(high[0]), "n": len(values)}


def summarise(rows: list[dict], pre_rl: list[dict]) -> dict:
    """Per option and method: iteration 0, first ``FIRST`` and last ``LAST`` iterations (mean successes
    per iteration, 95% t-interval over seeds); per option the VD-L2 average the rule uses; the rule."""
    runs: dict[tuple, list[float]] = {}
    for row in sorted(rows, key=lambda r: r["iteration"]):
        runs.setdefault((row["option"], row["method"], row["seed"]), []).append(row["successes"])
    per_run = {
        key: {"iteration0": v[0], "first": float(np.mean(v[:FIRST])), "last": float(np.mean(v[-LAST:]))}
        for key, v in runs.items()
    }
    options = list(dict.fromkeys(key[0] for key in runs))
    seeds = sorted({key[2] for key in runs})
    table = {
        option: {
            method: {
                q: _interval([per_run[(option, method, s)][q] for s in seeds]) for q in ("iteration0", "first", "last")
            }
            for method in ("vd", "l2", "none")
            if (option, method, seeds[0]) in per_run
        }
        for option in options
    }
    pooled = {
        option: {
            q: _interval([(per_run[(option, "vd", s)][q] + per_run[(option, "l2", s)][q]) / 2 for s in seeds])
            for q in ("first", "last")
        }
        for option in options
    }
    mean_action = {m: _interval([r["mean_action"] for r in pre_rl if r["method"] == m]) for m in ("vd", "l2")}
    level = float(np.mean([r["mean_action"] for r in pre_rl]))
    floor = pooled[options[0]]["last"]["low"]  # options[0]: the reference, (a) with the paper's 0.3
    eligible = [o for o in options if pooled[o]["last"]["mean"] >= floor]
    chosen = max(eligible, key=lambda o: pooled[o]["first"]["mean"])
    rule = {
        "eligible": eligible,
        "last_floor": floor,
        "chosen": chosen,
        "chosen_first": pooled[chosen]["first"]["mean"],
        "mean_action_level": level,
        "meets_mean_action_level": pooled[chosen]["first"]["mean"] >= level,
    }
    return {"per_option": table, "pooled_vd_l2": pooled, "mean_action_pre_rl": mean_action, "rule": rule}


def plot(rows: list[dict], window: int) -> Figure:
    """Learning curves per option (trailing mean over ``window`` iterations, 95% t-band over seeds, clipped to
    the possible values)."""
    options = list(dict.fromkeys(r["option"] for r in rows))
    fig = Figure(figsize=(3.2 * len(options), 3.6), layout="constrained")
    axes = fig.subplots(1, len(options), sharey=True, squeeze=False)[0]
    for ax, option in zip(axes, options):
        labelled = [{**r, "label": r["method"]} for r in rows if r["option"] == option]
        for name, curve in curves_from_rows(labelled, "successes", window).items():
            colour = method_entry(name).colour
            ax.plot(curve.steps, curve.mean, color=colour, label=f"{METHOD_LABELS[name]} (n={curve.seeds})")
            draw_band(ax, curve.steps, curve.low, curve.high, "successes", colour)
        spec = InitialSigma.parse(option)
        ax.set_title(f"sigma at start: {'fixed ' if spec.kind == 'fixed' else ''}{option}", fontsize=10)
        ax.set_xlabel("environment steps", fontsize=9)
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))  # 1e5 steps: plain ticks run into each other
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"successes per 200 steps\n(trailing mean of {window} iterations)", fontsize=9)
    axes[0].legend(fontsize=8)
    return fig


def run_study(
    seeds=(0, 1, 2, 3, 4),
    steps: int = 100_000,
    options=OPTIONS,
    workers: int = 2,
    out=None,
    window: int = 10,
    none_options=None,
) -> dict:
    """All runs of the study (in parallel, one torch thread each), then the files
    (module docstring, "Writes ``sigma_study.csv.gz``").
    ``none_options``: the options under which "no pre-training" is run (default: all; an option with
    the same starting sigma as a run one shares its rows; the others get no "none" curve)."""
    none_options = options if none_options is None else none_options
    out = Path(out) if out is not None else data_dir() / "results" / "sigma_study"
    scratch = runs_dir() / "sigma_study"
    starts = {}  # "none" once per distinct starting sigma: it has no demonstrations to fit to
    jobs = []
    for seed in seeds:
        for option in options:
            jobs += [_Run(m, option, seed, steps, scratch / f"{m}_{option}_seed{seed}.csv") for m in ("vd", "l2")]
            value = InitialSigma.parse(option).value
            if option in none_options and starts.setdefault(value, option) == option:
                jobs.append(_Run("none", option, seed, steps, scratch / f"none_{option}_seed{seed}.csv"))
    reused = sum(job.csv_path.exists() and len(read_rows(job.csv_path)) >= job.steps // EPISODE_STEPS for job in jobs)
    start = time.perf_counter()
    rows = [row for result in run_jobs(_run, jobs, workers) for row in result]
    pre_rl = run_jobs(_mean_action_job, [(m, s) for s in seeds for m in ("vd", "l2")], workers)
    for option in options:  # no pre-training's rows copied to every option with the same starting sigma
        source = starts.get(InitialSigma.parse(option).value, option)
        if source != option:
            rows += [
                {**r, "option": option}
                for r in rows
                if r["option"] == source and not method_entry(r["method"]).pretrains
            ]
    wall = time.perf_counter() - start
    rows = stored_rows(rows)  # the summary is what the shipped CSV gives back (runner.rows)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results_file(out, "sigma_study"), rows)
    save_png(plot(rows, window), out / "sigma_study.png", 110)
    summary = summarise(rows, pre_rl)
    command = shlex.join(
        [
            "python",
            "-m",
            "vdtutorial.experiments.sigma_study",
            "--seeds",
            *map(str, seeds),
            "--steps",
            str(steps),
            "--options",
            *options,
            "--none-options",
            *none_options,
            "--workers",
            str(workers),
            "--out",
            recorded_path(out),
        ]
    )
    record = {
        "command": command,
        "rule": "data/results/sigma_study/RULE.md",
        "options": list(options),
        "seeds": list(seeds),
        "steps": steps,
        "window": window,
        "wall_time_s": wall,
        "runs_read_from_earlier_calls": reused,
        "runs": len(jobs),
        "reuse_note": "runs read from the per-run CSVs (runs/sigma_study/) of earlier, interrupted calls with more "
        "seeds or steps: TRPO's first k iterations do not depend on the budget; wall_time_s covers "
        "this call only",
        "pretrain_config": asdict(default_config("vd")),
        "first_iterations": FIRST,
        "last_iterations": LAST,
        "none_note": "no pre-training starts from the fixed sigma of its option (0.3 for demos and spread); "
        "its runs are shared by the options with the same starting sigma",
        "mean_action_pre_rl_runs": pre_rl,
        "summary": summary,
        "versions": {
            "vdtutorial": vdtutorial.__version__,
            "torch": torch.__version__,
            "python": sys.version.split()[0],
        },
    }
    (out / "sigma_study.json").write_text(json.dumps(record, indent=1))
    return record


def build_parser() -> argparse.ArgumentParser:
    """The study's command line (its record's ``command`` is parsed by it in tests/test_provenance.py)."""
    parser = argparse.ArgumentParser(
        prog="python -m vdtutorial.experiments.sigma_study", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=100_000, help="RL env steps per run")
    parser.add_argument(
        "--options",
        nargs="+",
        default=list(OPTIONS),
        help="initial sigma options (the first is the rule's reference (a))",
    )
    parser.add_argument(
        "--none-options", nargs="+", default=None, help="options with a no-pre-training run (default: all)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="default: data/results/sigma_study")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    record = run_study(
        args.seeds,
        args.steps,
        tuple(args.options),
        args.workers,
        args.out,
        none_options=None if args.none_options is None else tuple(args.none_options),
    )
    print(json.dumps(record["summary"]["rule"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
