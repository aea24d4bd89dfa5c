"""The paper's experiments (Section V): Figs. 4-7 and Table I, as functions that write their evidence.

One *run* is one curve of one seed: pre-train (or load the checkpoint of) a policy, then fine-tune it with
TRPO and log one row per iteration. The methods compared are

    ``"vd"``     behavioural cloning with sparse variational dropout, prune log alpha > 3, then TRPO on the
                 weights of mu and sigma (the alphas stay frozen, pruned weights stay exactly 0);
    ``"l2"``     behavioural cloning with L2 weight decay, then TRPO;
    ``"none"``   TRPO from a random initialisation (a plain network, ``make_policy(..., variational=False)``);
    ``"expert"`` the IK expert of eqs. 9-10, measured, not trained: a horizontal reference line.

What a point of a curve is
    TRPO collects 200 environment steps per iteration (the paper's batch) on ``NUM_ENVS = 8``
    sub-environments for 25 steps each (25 = the horizon H), every sub-environment reset at the start of
    the iteration. One iteration is therefore the paper's "episode of 200 time steps", and its row's
    ``successes`` (trajectories that ended in success within the iteration) is the reach metric of
    Figs. 4-6. For grasping (Fig. 7) the metric is the "cumulative reward": ``mean_return``, the
    undiscounted return of the trajectories that ended in the iteration, averaged over them. That is the
    quantity for which the paper's expert "achieves a total cumulative reward of almost 20": with -1 per
    step and +25 for success, a successful grasp in about 5 steps returns about 20, whereas the reward
    summed over the 200 steps would be in the hundreds. The expert is measured in the same layout (8
    fresh 25-step runs per 200-step episode, trajectories cut off by the end not counted), so its line
    and the learners' curves count the same thing.

Seeds
    A seed is one independent replicate of the whole pipeline: it seeds pre-training (initialisation,
    minibatch order, validation split) *and* TRPO (environment resets, action noise). The band over
    seeds therefore includes the variance of pre-training. The demonstrations are the shipped data sets
    (demonstration seed 0) and are shared by all seeds, as in the paper, which used one data set per
    setting. Methods share seeds, so for a given seed all methods meet the same cups in the same order.

Smoothing and bands
    Each seed's curve is smoothed with a trailing moving average over ``window`` iterations (default
    ``SMOOTH_WINDOW`` = 25 iterations = 5000 env steps, 1.7% of the paper's 3e5; the first points average
    the iterations available so far). Trailing, so that a smoothed value at step x uses only what the run
    had seen by then, which keeps "the step at which VD first reaches L2's final level" honest. The band
    is a 95% Student-t confidence interval of the mean over seeds at each point:
    mean +- t_{0.975, n-1} * sd / sqrt(n) (no band for a single seed). With 3 seeds t = 4.30, so bands are
    wide: they show how much the seeds disagree, not a significance test.

Parallelism and reproducibility
    Runs are independent, so they go to a ``multiprocessing`` pool (``workers=2`` for 2 cores; "spawn"
    processes, which start clean instead of inheriting the parent's torch threads and pybullet clients).
    Every run -- in a worker or in-process with ``workers=1`` -- uses one torch thread and is a pure
    function of its seed, so the results do not depend on the number of workers. As with any spawned
    pool, a *script* that calls these functions with ``workers > 1`` must do so under
    ``if __name__ == "__main__":`` (notebooks and ``python -m vdtutorial`` need nothing).

Where files go
    Results: ``data/results/NAME/`` at full scale (the shipped reference curves); in quick mode
    ``runs/quick/NAME/`` next to ``data/`` (see ``RUNS_DIR``), so that a quick run never replaces the shipped
    full-scale results. Pre-trained checkpoints: ``data/checkpoints/`` (reused when they match the
    requested data set and configuration, regenerated and replaced when they do not); in quick mode the
    results folder, for the same reason. Each results folder holds ``runs/RUN.csv`` (TRPO's log of each
    run), ``NAME.csv`` (all runs, one row per iteration, labelled by method, data set and seed),
    ``NAME.png`` (the figure) and ``NAME.json`` (the exact command, every configuration, the summary).
"""
from __future__ import annotations

import csv
import json
import math
import multiprocessing
import shlex
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers import RecordEpisodeStatistics
from matplotlib.figure import Figure
from scipy import stats

import vdtutorial
from vdtutorial.demos import SHIPPED_NOISE, DemoFileError, Demos, demo_command, demo_path, generate_demos
from vdtutorial.envs import ENV_IDS, HORIZON
from vdtutorial.evaluation import EPISODE_STEPS, ExpertController, successes_per_episode
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.pretrain import (CheckpointError, PretrainConfig, checkpoint_path, default_config, load_checkpoint,
                                 pretrain, pretrain_command, save_checkpoint)
from vdtutorial.settings import DATA_DIR, QUICK, budget
from vdtutorial.trpo import TRPO, TRPOConfig, make_vec_env
from vdtutorial.vd import sparsity_report

RL_METHODS = ("vd", "l2", "none")
METHODS = RL_METHODS + ("expert",)
METHOD_LABELS = {"vd": "VD", "l2": "L2", "none": "no pre-training", "expert": "IK expert"}
#: Sub-environments of the vector env: 8 x 25 steps = one 200-step iteration (see the module docstring).
NUM_ENVS = EPISODE_STEPS // HORIZON
#: Row column plotted for each task: successes per 200-step episode (reach), cumulative reward (grasp).
METRIC = {"reach": "successes", "grasp": "mean_return"}
METRIC_LABELS = {"successes": "successful trajectories per 200-step episode",
                 "mean_return": "cumulative reward per trajectory"}
#: Trailing moving-average width, in TRPO iterations (200 env steps each).
SMOOTH_WINDOW = budget(25, 3)
#: Confidence level of the bands over seeds.
CONFIDENCE = 0.95
#: 200-step episodes measured per seed for the expert's reference line.
EXPERT_EPISODES = budget(5, 1)
#: The paper's RL budget, 3e5 env steps, and the quick one.
TOTAL_STEPS = budget(300_000, 2_000)
SEEDS = budget((0, 1, 2), (0, 1))
#: TRPO for image policies: Fisher-vector products on 10% of each batch, as in rllab (which the paper
#: used) -- they dominate the update of the convolutional networks (see ``TRPOConfig.fvp_subsample``).
IMAGE_TRPO_CONFIG = TRPOConfig(fvp_subsample=0.1)
#: Quick-mode results and ``reproduce_quick``'s default folder: ``runs/`` beside ``data/``, not shipped.
RUNS_DIR = DATA_DIR.parent / "runs"

#: Table I: (row, task, demonstrations, Sigma, the paper's neuron sparsification ratio).
TABLE1 = (
    ("8000 demonstrations; Sigma = 0.5", "reach", 8000, 0.5, 0.677),
    ("4000 demonstrations; Sigma = 0.5", "reach", 4000, 0.5, 0.526),
    ("2000 demonstrations; Sigma = 0.5", "reach", 2000, 0.5, 0.359),
    ("8000 demonstrations; Sigma = 0.25", "reach", 8000, 0.25, 0.685),
    ("8000 demonstrations; Sigma = 0.05", "reach", 8000, 0.05, 0.766),
    ("Grasping", "grasp", 8000, SHIPPED_NOISE["grasp"], 0.693),
)


# ----------------------------------------------------------------------------------------------
# One run: pre-trained policy -> TRPO; the expert's reference
# ----------------------------------------------------------------------------------------------
def default_trpo_config(obs_mode: str) -> TRPOConfig:
    """TRPO settings of the experiments: :data:`IMAGE_TRPO_CONFIG` for "rgbd", ``TRPOConfig()`` otherwise."""
    return IMAGE_TRPO_CONFIG if obs_mode == "rgbd" else TRPOConfig()


def load_demos(task: str, demos: Demos | str | Path | None = None, root: Path | None = None) -> Demos:
    """``demos`` as a data set: itself, loaded from a path, or (None) the task's shipped 8000-sample set
    (Sigma ``SHIPPED_NOISE[task]``) under ``root`` (default ``data/``). The task must match."""
    if isinstance(demos, Demos):
        if demos.meta.get("task") != task:
            raise ValueError(f"demonstrations of task {demos.meta.get('task')!r} given for task {task!r}")
        return demos
    return Demos.load(demos if demos is not None else demo_path(task, 8000, SHIPPED_NOISE[task], 0, root=root), task=task)


def pretrained_policy(reg: str, demos: Demos, obs_mode: str = "state", seed: int = 0,
                      config: PretrainConfig | None = None, checkpoints_root: Path | None = None,
                      progress: bool = False) -> GaussianPolicy:
    """The policy pre-trained with ``reg`` ("vd" or "l2") on ``demos``: loaded from its checkpoint
    (``pretrain.checkpoint_path`` under ``checkpoints_root``, default ``data/``, or ``runs/quick/`` in quick
    mode so that quick runs never replace shipped checkpoints) when that file was made
    from the same data set (task, samples, Sigma, demonstration seed) with the same pre-training
    configuration and seed; otherwise pre-trained now and saved there (replacing a stale file).

    The policy is always returned as read back from the checkpoint, so a fresh and a reused
    pre-training hand TRPO exactly the same object (parameters, and every ``requires_grad`` at its
    default: pre-training freezes sigma, the RL phase trains it). It is not pruned yet."""
    cfg = replace(config or default_config(reg, obs_mode), reg=reg, obs_mode=obs_mode)
    meta = demos.meta
    if checkpoints_root is None:  # quick mode never replaces the shipped full-scale checkpoints in data/
        checkpoints_root = budget(None, RUNS_DIR / "quick")
    path = checkpoint_path(meta, reg, obs_mode, seed, root=checkpoints_root)
    expected = {**{k: meta[k] for k in ("task", "samples", "noise", "seed")}, **asdict(cfg)}
    if path.exists():
        try:
            policy = load_checkpoint(path, **expected)
            if policy.pretrain_info.get("seed") == seed:
                return policy
            reason = f"checkpoint {path} was pre-trained with seed {policy.pretrain_info.get('seed')}, not {seed}"
        except CheckpointError as exc:
            reason = str(exc)
        warnings.warn(f"{reason}: pre-training again and replacing it", stacklevel=2)
    policy, _ = pretrain(demos, cfg, seed=seed, progress=progress)
    source = demo_path(meta["task"], meta["samples"], meta["noise"], meta["seed"])
    save_checkpoint(policy, path, extra={"command": pretrain_command(reg, source, seed, obs_mode)})
    return load_checkpoint(path)


def finetune(method: str, task: str = "reach", demos: Demos | str | Path | None = None, obs_mode: str = "state",
             seed: int = 0, total_steps: int | None = None, csv_path: str | Path | None = None, *,
             pretrain_config: PretrainConfig | None = None, trpo_config: TRPOConfig | None = None,
             num_envs: int = NUM_ENVS, checkpoints_root: Path | None = None,
             progress: bool = False) -> tuple[GaussianPolicy, list[dict]]:
    """One run of the RL stage: the policy of ``method`` ("vd", "l2" or "none") trained by TRPO for
    ``total_steps`` env steps (default 3e5) on ``num_envs`` copies of the task (default 8 x 25 = 200 steps
    per iteration). Returns the trained policy and TRPO's log rows; ``csv_path`` (replaced if it exists)
    receives the rows as they come.

    demos: the data set of the pre-training (a :class:`Demos` or a path; default the task's shipped
        8000-sample set); ignored by "none".
    pretrain_config: behavioural-cloning settings (``reg`` and ``obs_mode`` are set from ``method`` and
        ``obs_mode``); its ``image_size`` is also the camera's in the RL environment.
    trpo_config: default :func:`default_trpo_config` of ``obs_mode``.
    checkpoints_root: where pre-trained checkpoints are looked up and saved (see :func:`pretrained_policy`).
    """
    if method not in RL_METHODS:
        raise ValueError(f"method must be one of {RL_METHODS} (the expert is measured by expert_reference), "
                         f"got {method!r}")
    total_steps = TOTAL_STEPS if total_steps is None else total_steps
    cfg = pretrain_config or default_config(method if method != "none" else "l2", obs_mode)
    env = make_vec_env(ENV_IDS[task], num_envs, obs_mode=obs_mode, image_size=cfg.image_size)
    try:
        if method == "none":
            torch.manual_seed(seed)
            policy = make_policy(env.single_observation_space, env.single_action_space.shape[0], variational=False)
        else:
            policy = pretrained_policy(method, load_demos(task, demos), obs_mode, seed, cfg, checkpoints_root,
                                       progress)
            if method == "vd":
                policy.prune_()
        if csv_path is not None:
            Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
            Path(csv_path).unlink(missing_ok=True)  # TRPO appends: a stale file would mix two runs
        algo = TRPO(policy, env, trpo_config or default_trpo_config(obs_mode), seed=seed)
        rows = algo.run(total_steps, csv_path=csv_path, progress=progress)
    finally:
        env.close()
    return policy, rows


def expert_reference(task: str = "reach", seed: int = 0, episodes: int | None = None,
                     num_envs: int = NUM_ENVS) -> list[dict]:
    """The IK expert's score per 200-step episode, measured as TRPO's iterations count: each episode is
    ``num_envs`` runs of ``200 / num_envs`` steps from a fresh reset (the seeds of episode k derive
    from (seed, k)); trajectories still running at the end are not counted. One row per episode with
    ``successes``, ``failures``, ``episodes`` (trajectories that ended) and ``mean_return`` (their mean
    undiscounted return)."""
    episodes = EXPERT_EPISODES if episodes is None else episodes
    env = RecordEpisodeStatistics(gym.make(ENV_IDS[task], obs_mode="state"), buffer_length=EPISODE_STEPS)
    controller = ExpertController(env)
    rows = []
    for k in range(episodes):
        env.return_queue.clear()
        row = {"episode": k, "successes": 0, "failures": 0, "episodes": 0}
        for reset_seed in np.random.SeedSequence([seed, k]).generate_state(num_envs):
            counts = successes_per_episode(env, controller, steps=EPISODE_STEPS // num_envs, seed=int(reset_seed))
            row["successes"] += counts["successes"]
            row["failures"] += counts["failures"]
            row["episodes"] += counts["trajectories"]
        row["mean_return"] = float(np.mean(env.return_queue)) if env.return_queue else math.nan
        rows.append(row)
    env.close()
    return rows


# ----------------------------------------------------------------------------------------------
# Many runs, in parallel
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunSpec:
    """What one run is: a method, a data set (``samples``, ``noise``; None for "none" and "expert"), a
    seed. ``label`` names the curve it belongs to."""

    method: str
    task: str = "reach"
    samples: int | None = 8000
    noise: float | None = 0.5
    seed: int = 0
    obs_mode: str = "state"
    total_steps: int = TOTAL_STEPS
    label: str = ""

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.method in ("vd", "l2") and (self.samples is None or self.noise is None):
            raise ValueError(f"method {self.method!r} pre-trains: give the data set's samples and noise")

    @property
    def name(self) -> str:
        if self.method == "expert":
            return f"expert_{self.task}_seed{self.seed}"
        data = "" if self.method == "none" else f"_n{self.samples}_sigma{self.noise:g}"
        return f"{self.method}_{self.task}{data}_{self.obs_mode}_seed{self.seed}"


@dataclass(frozen=True)
class _Job:
    """A :class:`RunSpec` plus where its inputs and outputs live (what a worker process needs)."""

    spec: RunSpec
    csv_path: Path
    demos_root: Path | None
    checkpoints_root: Path | None
    pretrain_config: PretrainConfig | None
    trpo_config: TRPOConfig | None


def _run_job(job: _Job) -> dict:
    """Execute one run; returns its rows, each labelled with the spec, and its wall time."""
    spec, start = job.spec, time.perf_counter()
    if spec.method == "expert":
        rows = expert_reference(spec.task, spec.seed)
        _write_csv(job.csv_path, rows)
    else:
        demos = (None if spec.method == "none"
                 else demo_path(spec.task, spec.samples, spec.noise, 0, root=job.demos_root))
        _, rows = finetune(spec.method, spec.task, demos, spec.obs_mode, spec.seed, spec.total_steps, job.csv_path,
                           pretrain_config=job.pretrain_config, trpo_config=job.trpo_config,
                           checkpoints_root=job.checkpoints_root)
    tags = {"label": spec.label, "method": spec.method, "task": spec.task, "samples": spec.samples,
            "noise": spec.noise, "obs_mode": spec.obs_mode, "seed": spec.seed}
    return {"rows": [{**tags, **row} for row in rows], "seconds": time.perf_counter() - start}


def _one_thread() -> None:
    torch.set_num_threads(1)


def parallel_map(fn, jobs: list, workers: int = 2) -> list:
    """``[fn(job) for job in jobs]`` on ``workers`` spawned processes, each with one torch thread; with
    ``workers=1`` in this process, also with one torch thread (restored afterwards), so that the
    results are the same either way. ``fn`` must be a module-level function."""
    if workers <= 1 or len(jobs) <= 1:
        threads = torch.get_num_threads()
        _one_thread()
        try:
            return [fn(job) for job in jobs]
        finally:
            torch.set_num_threads(threads)
    context = multiprocessing.get_context("spawn")
    with context.Pool(min(workers, len(jobs)), initializer=_one_thread) as pool:
        results = pool.map(fn, jobs, chunksize=1)
        pool.close()  # let the workers exit on their own: terminating them leaks their semaphores
        pool.join()
    return results


# ----------------------------------------------------------------------------------------------
# Curves: smoothing, bands, the "steps to reach" summary
# ----------------------------------------------------------------------------------------------
def moving_average(values, window: int) -> np.ndarray:
    """Trailing moving average along the last axis: point i averages ``values[..., max(0, i-window+1):i+1]``."""
    values = np.asarray(values, dtype=np.float64)
    sums = np.cumsum(values, axis=-1)
    shifted = np.zeros_like(sums)
    if window < sums.shape[-1]:
        shifted[..., window:] = sums[..., :-window]
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (sums - shifted) / counts


def mean_band(samples, confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over axis 0 and its Student-t confidence interval, mean +- t_{(1+c)/2, n-1} sd / sqrt(n).
    With a single sample the interval is undefined: both bounds are NaN."""
    samples = np.asarray(samples, dtype=np.float64)
    n, mean = samples.shape[0], samples.mean(axis=0)
    if n < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan.copy()
    half = stats.t.ppf((1 + confidence) / 2, n - 1) * samples.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def steps_to_reach(steps, curve, level: float) -> float | None:
    """First ``steps[i]`` at which ``curve[i] >= level``, or None if the curve never gets there."""
    hits = np.flatnonzero(np.asarray(curve) >= level)
    return float(np.asarray(steps)[hits[0]]) if len(hits) else None


@dataclass
class Curve:
    """One labelled curve over seeds: smoothed mean and band against env steps. For the expert, whose
    line is flat, ``steps`` is empty and ``mean``, ``low``, ``high`` hold one number each."""

    label: str
    method: str
    steps: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    seeds: int


def curves_from_rows(rows: list[dict], metric: str, window: int = SMOOTH_WINDOW) -> dict[str, Curve]:
    """Group combined rows by label, smooth each seed's ``metric`` over iterations, and reduce over seeds
    (:func:`mean_band`). Expert rows (one per measured episode) become a flat line: the mean over all
    episodes of all seeds and its interval. Labels keep their order of first appearance."""
    groups: dict[str, dict] = {}
    for row in rows:
        group = groups.setdefault(row["label"], {"method": row["method"], "seeds": {}})
        group["seeds"].setdefault(row["seed"], []).append(row)
    curves = {}
    for label, group in groups.items():
        runs = list(group["seeds"].values())
        if group["method"] == "expert":
            values = np.array([r[metric] for run in runs for r in run], dtype=np.float64)
            mean, low, high = mean_band(values[:, None])
            curves[label] = Curve(label, "expert", np.array([]), mean, low, high, len(runs))
            continue
        runs = [sorted(run, key=lambda r: r["iteration"]) for run in runs]
        steps = np.array([r["env_steps"] for r in runs[0]], dtype=np.float64)
        if any(len(run) != len(steps) for run in runs):
            raise ValueError(f"the seeds of {label!r} have different numbers of iterations")
        smoothed = moving_average([[r[metric] for r in run] for run in runs], window)
        curves[label] = Curve(label, group["method"], steps, *mean_band(smoothed), len(runs))
    return curves


# ----------------------------------------------------------------------------------------------
# Files and the figure
# ----------------------------------------------------------------------------------------------
def _write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows with possibly different keys -> one CSV with the union of the columns (blank where absent)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
    return path


def _parse(value: str):
    if value == "":
        return None
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def read_rows(path: str | Path) -> list[dict]:
    """Read a combined results CSV back into rows (numbers as numbers, blanks as None)."""
    with open(path, newline="") as f:
        return [{k: _parse(v) for k, v in row.items()} for row in csv.DictReader(f)]


_COLOURS = {"vd": "tab:blue", "l2": "tab:orange", "none": "tab:gray", "expert": "black"}
_LINESTYLES = ("-", "--", ":", "-.")


def plot_curves(curves: dict[str, Curve], metric: str, title: str, window: int = SMOOTH_WINDOW) -> Figure:
    """Mean (line) and 95% t-interval over seeds (shaded) of each smoothed curve against env steps; the
    expert as a horizontal dashed line with its interval. Curves of one method are told apart by line
    style. Uses ``matplotlib.figure.Figure`` directly (no pyplot state), so it is safe in worker
    processes and notebooks alike."""
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    variants: dict[str, int] = {}
    for curve in curves.values():
        colour = _COLOURS[curve.method]
        if curve.method == "expert":
            ax.axhline(curve.mean[0], color=colour, linestyle="--", label=f"{curve.label} ({curve.mean[0]:.1f})")
            if np.isfinite(curve.low[0]):
                ax.axhspan(curve.low[0], curve.high[0], color=colour, alpha=0.08)
            continue
        style = _LINESTYLES[variants.get(curve.method, 0) % len(_LINESTYLES)]
        variants[curve.method] = variants.get(curve.method, 0) + 1
        ax.plot(curve.steps, curve.mean, color=colour, linestyle=style, label=f"{curve.label} (n={curve.seeds})")
        if np.isfinite(curve.low).any():
            ax.fill_between(curve.steps, curve.low, curve.high, color=colour, alpha=0.15, linewidth=0)
    ax.set_xlabel(f"environment steps\n(trailing mean over {window} iterations = {window * EPISODE_STEPS} steps; "
                  f"band: {CONFIDENCE:.0%} t-interval of the mean over seeds)", fontsize=9)
    ax.set_ylabel(METRIC_LABELS[metric])
    ax.set_title(title)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


@dataclass
class ExperimentResult:
    """What an experiment produced: its folder, all rows, the curves, the figure and a summary."""

    name: str
    out: Path
    rows: list[dict]
    curves: dict[str, Curve]
    figure: Figure
    summary: dict = field(default_factory=dict)


def experiment_command(name: str, **options) -> str:
    """The command line of an experiment (``python -m vdtutorial experiment NAME --option value ...``)."""
    parts = ["python", "-m", "vdtutorial", "experiment", name]
    for key, value in options.items():
        if value is None:
            continue
        flag = "--" + key.replace("_", "-")
        parts += [flag, *map(str, value)] if isinstance(value, (tuple, list)) else [flag, str(value)]
    return shlex.join(parts)


def _default_out(name: str) -> Path:
    return Path(budget(DATA_DIR / "results" / name, RUNS_DIR / "quick" / name))


def run_experiment(name: str, specs: list[RunSpec], title: str, out: str | Path | None = None, workers: int = 2,
                   demos_root: Path | None = None, checkpoints_root: Path | None = None,
                   pretrain_config: PretrainConfig | None = None, trpo_config: TRPOConfig | None = None,
                   window: int = SMOOTH_WINDOW, command: str = "", summarise=None) -> ExperimentResult:
    """Run ``specs`` (in parallel), then write ``runs/RUN.csv`` per run, ``NAME.csv`` (all rows),
    ``NAME.png`` (:func:`plot_curves`) and ``NAME.json`` (command, configuration, per-run wall times,
    summary) into ``out``. The summary holds each curve's final point, plus whatever
    ``summarise(curves)`` returns. Defaults: ``out`` as in the module docstring; demonstrations from
    ``data/``; checkpoints in ``data/`` at full scale and in ``out`` in quick mode."""
    out = Path(out) if out is not None else _default_out(name)
    checkpoints_root = checkpoints_root if checkpoints_root is not None else budget(None, out)
    trpo_config = trpo_config or default_trpo_config(specs[0].obs_mode)
    task = specs[0].task
    metric = METRIC[task]
    jobs = [_Job(spec, out / "runs" / f"{spec.name}.csv", demos_root, checkpoints_root, pretrain_config,
                 trpo_config) for spec in specs]
    start = time.perf_counter()
    results = parallel_map(_run_job, jobs, workers)
    wall = time.perf_counter() - start
    rows = [row for result in results for row in result["rows"]]
    _write_csv(out / f"{name}.csv", rows)
    curves = curves_from_rows(rows, metric, window)
    figure = plot_curves(curves, metric, title, window)
    figure.savefig(out / f"{name}.png", dpi=120)
    summary = {"final": {label: _final(curve) for label, curve in curves.items()},
               **(summarise(curves) if summarise else {})}
    record = {
        "experiment": name, "command": command, "argv": sys.argv, "quick": QUICK, "title": title,
        "metric": metric, "num_envs": NUM_ENVS, "steps_per_iteration": trpo_config.steps_per_iter,
        "window": window, "smoothing": f"trailing moving average over {window} iterations", "band": f"{CONFIDENCE:.0%} Student-t "
        "interval of the mean over seeds", "workers": workers, "wall_time_s": wall,
        "pretrain_config": {k: v for k, v in asdict(pretrain_config or default_config("vd", specs[0].obs_mode)).items()
                            if k not in ("reg", "obs_mode")},  # these two are set per run
        "trpo_config": asdict(trpo_config),
        "demos_root": str(demos_root or DATA_DIR), "checkpoints_root": str(checkpoints_root or DATA_DIR),
        "runs": [{**asdict(job.spec), "name": job.spec.name, "seconds": result["seconds"]}
                 for job, result in zip(jobs, results)],
        "summary": summary,
        "versions": {"vdtutorial": vdtutorial.__version__, "torch": torch.__version__, "gymnasium": gym.__version__,
                     "numpy": np.__version__, "python": sys.version.split()[0]},
    }
    (out / f"{name}.json").write_text(json.dumps(record, indent=1, default=str))
    return ExperimentResult(name, out, rows, curves, figure, summary)


def _final(curve: Curve) -> dict:
    """Last point of a smoothed curve (the expert's level for the expert)."""
    return {"mean": float(curve.mean[-1]), "low": float(curve.low[-1]), "high": float(curve.high[-1]),
            "seeds": curve.seeds}


def vd_reaches_l2_final(curves: dict[str, Curve]) -> dict:
    """The paper's headline comparison (Section V-A): the env steps at which VD's smoothed mean curve first
    reaches the final level of L2's (paper: ~1.25e5 of 3e5, "less than one quarter as many samples");
    ``steps`` is None when it never does."""
    vd, l2 = curves[METHOD_LABELS["vd"]], curves[METHOD_LABELS["l2"]]
    level, budget_steps = float(l2.mean[-1]), float(l2.steps[-1])
    steps = steps_to_reach(vd.steps, vd.mean, level)
    if steps is None:
        text = f"VD's smoothed mean never reaches L2's final level ({level:.2f}) (paper: it does at ~1.25e5 of 3e5)"
    else:
        text = (f"VD's smoothed mean first reaches L2's final level ({level:.2f}) at {steps:.3g} env steps, "
                f"{steps / budget_steps:.0%} of the budget (paper: ~1.25e5 of 3e5, < 25%)")
    return {"l2_final_level": level, "steps": steps,
            "fraction_of_budget": None if steps is None else steps / budget_steps, "text": text}


# ----------------------------------------------------------------------------------------------
# The figures
# ----------------------------------------------------------------------------------------------
def _figure(name: str, title: str, methods, task: str, seeds, total_steps, obs_mode, out, workers,
            datasets=((8000, 0.5),), label=None, **kwargs) -> ExperimentResult:
    """The runs of a figure -- each pre-training method on each data set, the other methods once, every
    one for every seed -- handed to :func:`run_experiment`. ``label(method, samples, noise)`` names the
    pre-trained curves (default: the method's name)."""
    seeds = tuple(SEEDS if seeds is None else seeds)
    total_steps = TOTAL_STEPS if total_steps is None else total_steps
    label = label or (lambda method, samples, noise: METHOD_LABELS[method])
    specs = []
    for method in methods:
        if method in ("vd", "l2"):
            specs += [RunSpec(method, task, n, sigma, seed, obs_mode, total_steps, label(method, n, sigma))
                      for n, sigma in datasets for seed in seeds]
        else:
            specs += [RunSpec(method, task, None, None, seed, obs_mode, total_steps, METHOD_LABELS[method])
                      for seed in seeds]
    trpo_config = kwargs.get("trpo_config")
    fvp_subsample = None  # in the command only when it is not the default of obs_mode
    if trpo_config is not None and trpo_config.fvp_subsample != default_trpo_config(obs_mode).fvp_subsample:
        fvp_subsample = trpo_config.fvp_subsample
    command = experiment_command(name, seeds=seeds, steps=total_steps, obs=obs_mode, workers=workers, out=out,
                                 fvp_subsample=fvp_subsample)
    return run_experiment(name, specs, title, out, workers, command=command, **kwargs)


def fig4(seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2,
         **kwargs) -> ExperimentResult:
    """Fig. 4: VD vs L2 vs no pre-training vs the IK expert on reaching (8000 demonstrations, Sigma = 0.5),
    plus the paper's headline number: the env steps at which VD's smoothed mean curve first reaches L2's
    final level (paper: ~1.25e5 of 3e5), in ``result.summary["vd_reaches_l2_final"]`` (None: never).
    ``kwargs`` go to :func:`run_experiment` (``demos_root``, ``checkpoints_root``, configs, ``window``)."""
    return _figure("fig4", "Fig. 4: reaching, different pre-training", ("vd", "l2", "none", "expert"), "reach",
                   seeds, total_steps, obs_mode, out, workers,
                   summarise=lambda curves: {"vd_reaches_l2_final": vd_reaches_l2_final(curves)}, **kwargs)


def fig5(seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2,
         **kwargs) -> ExperimentResult:
    """Fig. 5: VD and L2 pre-trained on 2000, 4000 and 8000 demonstrations (Sigma = 0.5), reaching."""
    return _figure("fig5", "Fig. 5: reaching, data set size", ("vd", "l2"), "reach", seeds, total_steps, obs_mode,
                   out, workers, datasets=((2000, 0.5), (4000, 0.5), (8000, 0.5)),
                   label=lambda m, n, s: f"{METHOD_LABELS[m]}, {n} demos", **kwargs)


def fig6(seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2,
         **kwargs) -> ExperimentResult:
    """Fig. 6: VD and L2 pre-trained on 8000 demonstrations with Sigma = 0.05, 0.25 and 0.5, reaching."""
    return _figure("fig6", "Fig. 6: reaching, expert noise", ("vd", "l2"), "reach", seeds, total_steps, obs_mode,
                   out, workers, datasets=((8000, 0.05), (8000, 0.25), (8000, 0.5)),
                   label=lambda m, n, s: f"{METHOD_LABELS[m]}, Sigma={s:g}", **kwargs)


def fig7(seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2,
         **kwargs) -> ExperimentResult:
    """Fig. 7: grasping, VD vs L2 vs no pre-training vs the IK expert, in cumulative reward per trajectory
    (8000 demonstrations, Sigma = ``SHIPPED_NOISE["grasp"]``)."""
    return _figure("fig7", "Fig. 7: grasping", ("vd", "l2", "none", "expert"), "grasp", seeds, total_steps,
                   obs_mode, out, workers, datasets=((8000, SHIPPED_NOISE["grasp"]),), **kwargs)


# ----------------------------------------------------------------------------------------------
# Table I
# ----------------------------------------------------------------------------------------------
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
           checkpoints_root: Path | None = None, pretrain_config: PretrainConfig | None = None) -> list[dict]:
    """Table I: neuron sparsification of the VD-pre-trained mu on each of the five reaching data sets and
    the grasping set, beside the paper's ratios, plus the fraction of weights pruned. Reuses (or makes)
    the same checkpoints as the fine-tuning runs. Writes ``table1.csv`` and ``table1.txt`` into ``out``
    (default ``data/results/table1``; quick mode: ``runs/quick/table1``), prints the table, and returns
    the rows."""
    out = Path(out) if out is not None else _default_out("table1")
    checkpoints_root = checkpoints_root if checkpoints_root is not None else budget(None, out)
    jobs = [_SparsityJob(demo_path(task, samples, noise, 0, root=demos_root), obs_mode, seed, checkpoints_root,
                         pretrain_config) for _, task, samples, noise, _ in TABLE1]
    measured = parallel_map(_sparsity_job, jobs, workers)
    rows = [{"experiment": row, "task": task, "samples": samples, "noise": noise, "obs_mode": obs_mode, "seed": seed,
             **m, "neuron_fraction_paper": paper} for (row, task, samples, noise, paper), m in zip(TABLE1, measured)]
    _write_csv(out / "table1.csv", rows)
    text = format_table1(rows)
    command = experiment_command("table1", obs=obs_mode, seeds=(seed,), workers=workers, out=out)
    (out / "table1.txt").write_text(f"{text}\n\ncommand: {command}\npretrain config: "
                                    f"{asdict(pretrain_config or default_config('vd', obs_mode))}\n")
    print(text)
    return rows


# ----------------------------------------------------------------------------------------------
# The whole pipeline, small
# ----------------------------------------------------------------------------------------------
def reproduce_quick(out=None, seeds=(0, 1, 2), samples: int | None = None, noise: float = 0.5,
                    epochs: int | None = None, total_steps: int | None = None, workers: int = 2) -> ExperimentResult:
    """The paper's pipeline end to end at a small scale, in a few minutes on 2 cores: generate a small
    reaching data set, pre-train VD and L2 on it, fine-tune VD, L2 and no pre-training with TRPO, and
    draw the Fig. 4-style curves. There is no expert line: it would cost a worker ~40 s, and at ~75
    successes per episode it would flatten curves that are still in single digits at this budget. The
    VD policy's sparsity (``sparsity_report(policy.mu)``, seed ``seeds[0]``) is printed and written to
    ``sparsity.txt``; ``result.summary`` carries it and the fig4-style "steps to reach L2's final level".

    Everything -- demonstrations, checkpoints, results -- goes to ``out`` (default ``runs/reproduce_quick``
    beside ``data/``), so the shipped full-scale artefacts are never touched. Quick mode shrinks the
    defaults further."""
    out = Path(out) if out is not None else RUNS_DIR / "reproduce_quick"
    samples = budget(2000, 300) if samples is None else samples
    epochs = budget(60, 4) if epochs is None else epochs
    total_steps = budget(50_000, 1_000) if total_steps is None else total_steps
    path = demo_path("reach", samples, noise, 0, root=out)
    try:
        Demos.load(path, task="reach", samples=samples, noise=noise, seed=0)
    except DemoFileError:  # missing, corrupt or another set: make it
        generate_demos("reach", samples, noise, 0, progress=False).save(path)
    config = PretrainConfig(epochs=epochs)
    specs = [RunSpec(m, "reach", *((samples, noise) if m != "none" else (None, None)), seed, "state", total_steps,
                     METHOD_LABELS[m]) for m in RL_METHODS for seed in seeds]
    command = (f"python -c 'from vdtutorial.experiments import reproduce_quick; reproduce_quick(out={str(out)!r}, "
               f"seeds={tuple(seeds)}, samples={samples}, noise={noise}, epochs={epochs}, total_steps={total_steps})'"
               f"  # demonstrations: {demo_command('reach', samples, noise, 0)} --out {path}")

    def summarise(curves: dict[str, Curve]) -> dict:
        report = sparsity_report(pretrained_policy("vd", Demos.load(path), "state", seeds[0], config, out).mu)
        (out / "sparsity.txt").write_text(f"{report}\n")
        print(report)
        return {"neuron_fraction": report.neuron_fraction, "weight_fraction": report.weight_fraction,
                "vd_reaches_l2_final": vd_reaches_l2_final(curves)}

    title = f"Quick reproduction: reaching, {samples} demos, {total_steps} steps"
    return run_experiment("reproduce_quick", specs, title, out, workers, demos_root=out, checkpoints_root=out,
                          pretrain_config=config, command=command, summarise=summarise)
