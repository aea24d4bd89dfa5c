"""Image pre-training stopped on the held-out loss against our fixed 40 epochs.

The image checkpoints behind ``fig4_rgbd`` clone for 40 epochs, a budget of ours (the paper gives none), and VD's
seed 2 was still improving at the end. Here each image checkpoint (reaching, 8000 demonstrations, Sigma 0.5;
VD and L2; seeds 0-2) is made again with ``PretrainConfig.patience`` (:func:`stop_config`: the same 40 epochs of
KL warm-up, then on until the held-out MSE has not improved for :data:`PATIENCE` epochs, at most :data:`CAP`),
and both kinds of checkpoint are measured the same way: the mean action's successes before RL
(:func:`~vdtutorial.experiments.evaluation.mean_action_successes`) and the first :func:`rl_steps` env steps of TRPO
with the
figures' settings (the fixed checkpoints' runs are then the first iterations of ``fig4_rgbd``'s). Per method,
the difference stopped - fixed at the pre-RL level and over the early RL curve, 95% Welch intervals over seeds.
If it is material (:func:`is_material`), ``fig4_rgbd`` is to be made again from the stopped checkpoints; if not,
this is its control.

Taught in appendix A1.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure

import vdtutorial
from vdtutorial.demos import Demos, demo_path
from vdtutorial.experiments.checkpoints import default_config, with_held_out_stop
from vdtutorial.experiments.curves import curves_from_rows
from vdtutorial.experiments.effects import welch_interval
from vdtutorial.experiments.evaluation import EPISODE_STEPS, mean_action_successes
from vdtutorial.experiments.jobs import Job, RunSpec
from vdtutorial.experiments.measures import measures_of
from vdtutorial.experiments.plots import figure_title, plot_measures, save_png
from vdtutorial.experiments.results import default_out, experiment_command
from vdtutorial.experiments.pipeline import pretrained_policy, ready_for_rl
from vdtutorial.experiments.runs import CHECKPOINT_EVERY, NUM_ENVS, default_seeds, default_trpo_config
from vdtutorial.methods import METHOD_LABELS
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner import SavedInStateDir, results_file, run_grid, write_csv
from vdtutorial.runner.resume import save_finished_rows
from vdtutorial.settings import budget, data_dir, is_quick

TASK, SAMPLES, NOISE, OBS = "reach", 8000, 0.5, "rgbd"
#: Epochs without a better held-out MSE before cloning stops, and the most epochs it may take.
PATIENCE, CAP = 10, 200
#: The two kinds of checkpoint: the figures' fixed epochs, and stopped on the held-out loss.
FIXED, STOPPED = "fixed 40 epochs", "held-out stop"
#: Iterations of the RL curves' trailing mean in the figure: the runs are 50 iterations long, too short for the
#: figures' 25.
RL_WINDOW = 5


def stop_config(reg: str) -> PretrainConfig:
    """The figures' image settings with the held-out stop: the cap in place of the fixed epochs, the KL warm-up
    kept at the fixed run's length in epochs (so the first 40 epochs see the same beta schedule)."""
    fixed = default_config(reg, OBS)
    return with_held_out_stop(fixed, budget(CAP, 2 * fixed.epochs), budget(PATIENCE, 1))


def configs() -> dict[str, dict[str, PretrainConfig]]:
    return {
        FIXED: {reg: default_config(reg, OBS) for reg in ("vd", "l2")},
        STOPPED: {reg: stop_config(reg) for reg in ("vd", "l2")},
    }


def rl_steps() -> int:
    """RL env steps per run: 50 TRPO iterations (quick mode: 2)."""
    return budget(50, 2) * default_trpo_config().steps_per_iter


def pre_rl_episodes() -> int:
    """200-step episodes per pre-RL score (quick mode: one)."""
    return budget(5, 1)


@dataclass(frozen=True)
class PreRLJob(SavedInStateDir):
    """Clone (or find) one checkpoint and score its mean action before RL, as a job of the grid runner; its one
    row records the epochs the cloning ran and the epoch whose mu it kept."""

    kind: str
    reg: str
    seed: int
    out: Path
    state_dir: Path

    @property
    def name(self) -> str:
        return f"pre-rl/{self.kind.replace(' ', '-')}_{self.reg}_seed{self.seed}"

    @property
    def settings(self) -> dict:
        return {
            "experiment": "pretrain_stop",
            "kind": self.kind,
            "reg": self.reg,
            "seed": self.seed,
            "episodes": pre_rl_episodes(),
            "pretrain_config": asdict(configs()[self.kind][self.reg]),
        }

    rows_expected = 1

    @property
    def env_steps(self) -> int:
        return pre_rl_episodes() * EPISODE_STEPS

    def tags(self) -> dict:
        return {
            "label": f"{METHOD_LABELS[self.reg]}, {self.kind}",
            "kind": self.kind,
            "method": self.reg,
            "seed": self.seed,
            "stage": "pre-RL",
        }

    def summary(self, rows: list[dict]) -> str:
        return f"{rows[0]['successes']:.3g} successes per 200 steps before RL after {rows[0]['epochs_run']} epochs"

    def compute(self):
        start = time.perf_counter()
        config = configs()[self.kind][self.reg]
        demos = Demos.load(demo_path(TASK, SAMPLES, NOISE, 0))
        policy = pretrained_policy(self.reg, demos, OBS, self.seed, config, self.out)
        info = policy.pretrain_info
        policy = ready_for_rl(self.reg, policy)
        score = mean_action_successes(policy, TASK, self.seed, pre_rl_episodes(), NUM_ENVS, OBS, config.image_size)
        history = info["history"]
        best = info.get("best_epoch", len(history))
        rows = [
            {
                **score,
                "epochs_run": info.get("epochs_run", len(history)),
                "best_epoch": best,
                "val_mse": history[best - 1]["val_mse"],
            }
        ]
        save_finished_rows(self.state_path, self.settings, rows, time.perf_counter() - start)
        yield {"env_steps": self.env_steps}
        return rows


@dataclass(frozen=True)
class _RLJob(Job):
    """A ``fig4_rgbd`` run of :func:`rl_steps` env steps from one kind of checkpoint."""

    kind: str = FIXED

    @property
    def name(self) -> str:
        return f"rl/{self.kind.replace(' ', '-')}_{self.spec.name}"

    def tags(self) -> dict:
        return {**super().tags(), "kind": self.kind, "stage": "RL"}


def jobs(seeds, out: Path, state_dir: Path) -> list:
    """The pre-RL jobs first (they make the stopped checkpoints), then the RL runs."""
    pre = [
        PreRLJob(kind, reg, seed, out, state_dir) for kind in (FIXED, STOPPED) for reg in ("vd", "l2") for seed in seeds
    ]
    rl = []
    for kind, per_reg in configs().items():
        for reg, config in per_reg.items():
            for seed in seeds:
                spec = RunSpec(reg, TASK, SAMPLES, NOISE, seed, OBS, rl_steps(), f"{METHOD_LABELS[reg]}, {kind}")
                stem = state_dir / "rl" / f"{kind.replace(' ', '-')}_{spec.name}"
                rl.append(
                    _RLJob(
                        spec,
                        Path(f"{stem}.pt"),
                        Path(f"{stem}.csv"),
                        data_dir().resolve(),
                        out.resolve(),
                        config,
                        default_trpo_config(),
                        CHECKPOINT_EVERY,
                        kind=kind,
                    )
                )
    return pre + rl


def _rl_steps_of(rows: list[dict]) -> int:
    """The env steps of the RL runs in ``rows`` (not :func:`rl_steps`, which depends on the mode a reader is in)."""
    return max(r["env_steps"] for r in rows if r["stage"] == "RL")


def compare(rows: list[dict], seeds) -> list[dict]:
    """Per method: stopped - fixed in the epochs, the pre-RL successes, and the mean successes per iteration of
    the RL runs (95% Welch intervals over seeds)."""
    out, steps = [], _rl_steps_of(rows)
    for reg in ("vd", "l2"):

        def values(kind, stage, key):
            picked = [r for r in rows if r["method"] == reg and r["kind"] == kind and r["stage"] == stage]
            if stage == "RL":
                return [float(np.mean([r[key] for r in picked if r["seed"] == s])) for s in seeds]
            return [float(r[key]) for r in sorted(picked, key=lambda r: r["seed"])]

        for stage, key, what in (
            ("pre-RL", "epochs_run", "epochs of cloning"),
            ("pre-RL", "val_mse", "held-out MSE of the kept mu"),
            ("pre-RL", "successes", "successes per 200 steps before RL (mean action)"),
            ("RL", "successes", f"successes per 200 steps, mean over the first {steps:g} RL steps"),
        ):
            stopped, fixed = values(STOPPED, stage, key), values(FIXED, stage, key)
            estimate, low, high = welch_interval(stopped, fixed, 0.95)
            out.append(
                {
                    "method": reg,
                    "measure": what,
                    "stopped": stopped,
                    "fixed": fixed,
                    "estimate": estimate,
                    "low": low,
                    "high": high,
                }
            )
    return out


def is_material(comparison: list[dict]) -> bool:
    """Whether the stop changed what RL starts from: for either method, the 95% interval of stopped - fixed of the
    successes (before RL, or over the early RL curve) excludes zero. The epochs and the held-out MSE are how
    the stop got there, not a difference a learner of Fig. 4 would see, so they do not count."""
    return any(c["low"] > 0 or c["high"] < 0 for c in comparison if c["measure"].startswith("successes"))


def plot(rows: list[dict], seeds) -> Figure:
    """The RL runs from both kinds of checkpoint, one panel per measure (the paper's count, the success rate,
    the env steps per trajectory), per seed thin behind the mean; the stopped checkpoints dashed."""
    rl = [r for r in rows if r["stage"] == "RL"]
    title = figure_title(
        "Image pre-training stopped on the held-out loss against the fixed 40 epochs: the first "
        "TRPO iterations (reaching)",
        OBS,
        _rl_steps_of(rows),
        len(seeds),
    )
    return plot_measures({m: curves_from_rows(rl, m, RL_WINDOW) for m in measures_of("successes")}, title, RL_WINDOW)


def pretrain_stop(
    seeds=None,
    out=None,
    workers: int = 2,
    progress: bool | None = None,
    backend: str = "local",
    address: str | None = None,
    restart: bool = False,
    state_dir=None,
) -> dict:
    """Run the comparison (module docstring, "Per method") as one resumable grid; write ``pretrain_stop.csv.gz``,
    ``pretrain_stop.png`` (:func:`plot`) and ``pretrain_stop.json`` into ``out`` (default ``runs/pretrain_stop``;
    shipped: ``data/results/pretrain_stop``)."""
    seeds = tuple(default_seeds() if seeds is None else seeds)
    out = Path(out) if out is not None else default_out("pretrain_stop")
    state_dir = Path(state_dir).resolve() if state_dir is not None else (out / "runs").resolve()
    start = time.perf_counter()
    results = run_grid(
        "pretrain_stop", jobs(seeds, out.resolve(), state_dir), workers, backend, address, restart, progress
    )
    rows = [row for result in results for row in result["rows"]]
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results_file(out, "pretrain_stop"), rows)
    save_png(plot(rows, seeds), out / "pretrain_stop.png", 110)
    comparison = compare(rows, seeds)
    shown_out = out if out != default_out("pretrain_stop") else None
    record = {
        "experiment": "pretrain_stop",
        "command": experiment_command("pretrain_stop", seeds=seeds, workers=workers, out=shown_out),
        "quick": is_quick(),
        "task": TASK,
        "samples": SAMPLES,
        "noise": NOISE,
        "obs_mode": OBS,
        "seeds": list(seeds),
        "rl_steps": rl_steps(),
        "pre_rl_episodes": pre_rl_episodes(),
        "patience": PATIENCE,
        "cap": CAP,
        "pretrain_config": {kind: {reg: asdict(c) for reg, c in per.items()} for kind, per in configs().items()},
        "comparison": comparison,
        "material": is_material(comparison),
        "run_seconds": sum(result["seconds"] for result in results),  # every job's, over all invocations
        "wall_time_s": time.perf_counter() - start,
        "versions": {
            "vdtutorial": vdtutorial.__version__,
            "torch": torch.__version__,
            "python": sys.version.split()[0],
        },
    }
    (out / "pretrain_stop.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def format_comparison(record: dict) -> str:
    """A line per method and measure: stopped and fixed per seed, and the difference with its interval; then
    what that means for ``fig4_rgbd`` (:func:`is_material`)."""
    consequence = (
        "material: fig4_rgbd is to be made again from the stopped checkpoints"
        if record["material"]
        else "not material (no interval of the successes excludes zero): fig4_rgbd keeps its fixed 40 epochs "
        "and this comparison is its control"
    )
    lines = [
        f"{METHOD_LABELS[c['method']]:>3} {c['measure']}: stopped {np.round(c['stopped'], 3).tolist()}, "
        f"fixed {np.round(c['fixed'], 3).tolist()}; stopped - fixed {c['estimate']:+.3g} "
        f"({c['low']:+.3g} to {c['high']:+.3g})"
        for c in record["comparison"]
    ]
    return "\n".join([*lines, f"{len(record['seeds'])} seeds, 95% Welch intervals; {consequence}"])
