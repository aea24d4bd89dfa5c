"""Beyond the paper (issue 33): learned demonstration noise (DART) and DAgger beside the hand-set Sigma.

The paper's Section VI asks for "techniques for learning appropriate expert noise from the data" and calls
DAgger "computationally quite expensive". This experiment measures both on reaching, in state mode, at an
equal number of expert labels (``SAMPLES``, Fig. 4's 8000):

* hand-set Sigma: the paper's 0.05, 0.25 and 0.5 (the shipped data sets) and a too-large ``TOO_LARGE``;
* DART (:mod:`vdtutorial.dart`) from a poor start, Sigma_0 = 0.05 and ``TOO_LARGE``, ``ROUNDS`` rounds;
* DAgger (:mod:`vdtutorial.dagger`), ``ROUNDS`` rounds, round 0 noise-free;

each cloned with VD and with L2. DART's and DAgger's rounds clone with the regulariser they are measured
with, so each makes its own data set per regulariser. As in Figs. 4-7 a data set is made once (data seed
0) and shared by the seeds; a seed is a replicate of the pre-training (and would be of the RL stage).

Measured per data set and seed: the pre-trained policy's mean-action score before RL, counted as TRPO
counts an iteration (:func:`vdtutorial.evaluation.mean_action_successes`: successes and finished trajectories
per 200-step episode, their ratio the success rate), and per data set the expert queries, the wall time
spent in the expert and the number of clonings it took. The comparisons (the JSON's ``comparisons``) are
differences of means over seeds with Welch t intervals, Bonferroni-corrected over all comparisons of the
experiment, read with the verdicts of :mod:`vdtutorial.experiments.effects`.

Taught in chapter 09.
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
from vdtutorial.dagger import BETA, dagger
from vdtutorial.dart import dart
from vdtutorial.demos import Demos, demo_path, generate_demos
from vdtutorial.evaluation import EPISODE_STEPS, mean_action_successes
from vdtutorial.experiments.curves import CONFIDENCE, mean_band
from vdtutorial.experiments.effects import verdict, welch_interval
from vdtutorial.experiments.results import default_out, experiment_command
from vdtutorial.experiments.runs import METHOD_LABELS, NUM_ENVS, pretrained_policy
from vdtutorial.imitation_rounds import cloning_config
from vdtutorial.pretrain import CheckpointError, load_checkpoint, pretrain, save_checkpoint
from vdtutorial.runner import results_file, run_grid, write_csv
from vdtutorial.runner.resume import save_finished_rows
from vdtutorial.settings import budget, is_quick, recorded_path

TASK = "reach"
#: Sigma values of the paper's Fig. 6, the hand-set ones.
HAND_SET = (0.05, 0.25, 0.5)
#: A Sigma larger than any of the paper's: the arm's step is at most pi/5 = 0.63 rad per joint, so noise of
#: 1 rad per joint drowns the expert's own motion.
TOO_LARGE = 1.0
#: DART's poor starts: the smallest hand-set Sigma and the too-large one.
DART_STARTS = (0.05, TOO_LARGE)
#: What the RL stage would be, and why it is not run here.
RL_STAGE = ("not run yet: TRPO at 1e5 env steps from these policies needs finetune_steps (experiments/runs.py) to "
            "start from a policy cloned on a DART or DAgger data set, whereas it looks the policy up by the data set's "
            "(samples, Sigma) name, which those sets do not have")


def samples() -> int:
    """Expert labels per data set: 8000 (quick mode: 300)."""
    return budget(8000, 300)


def rounds() -> int:
    """Rounds of DART and DAgger: 4 of 2000 labels (quick mode: 3 of 100)."""
    return budget(4, 3)


def pre_rl_episodes() -> int:
    """200-step episodes per pre-RL score (quick mode: one)."""
    return budget(5, 1)


@dataclass(frozen=True)
class Variant:
    """One data set and the regulariser it is cloned with: ``kind`` "hand-set" (``sigma`` its Sigma),
    "dart" (``sigma`` its start) or "dagger"."""

    kind: str
    reg: str
    sigma: float | None = None

    @property
    def label(self) -> str:
        reg = METHOD_LABELS[self.reg]
        if self.kind == "hand-set":
            return f"{reg}, Sigma={self.sigma:g}"
        return f"{reg}, DART from Sigma={self.sigma:g}" if self.kind == "dart" else f"{reg}, DAgger"

    @property
    def name(self) -> str:
        sigma = "" if self.sigma is None else f"_sigma{self.sigma:g}"
        return f"{self.kind}_{self.reg}{sigma}"


def variants() -> list[Variant]:
    """Every data set of the experiment, VD's and L2's."""
    return [v for reg in ("vd", "l2") for v in (
        *(Variant("hand-set", reg, s) for s in (*HAND_SET, TOO_LARGE)),
        *(Variant("dart", reg, s) for s in DART_STARTS), Variant("dagger", reg))]


def data_set(variant: Variant, out: Path, progress: bool = False) -> tuple[Demos, dict]:
    """The variant's data set and how it was made (rounds, expert time), made once and kept in ``out/demos``.
    A hand-set one is the shipped file when there is one of this size."""
    n = samples()
    if variant.kind == "hand-set":
        shipped = demo_path(TASK, n, variant.sigma, 0)
        path = shipped if shipped.exists() else demo_path(TASK, n, variant.sigma, 0, root=out)
        if not path.exists():
            generate_demos(TASK, n, variant.sigma, 0, progress).save(path)
        return Demos.load(path, task=TASK, samples=n), {"source": recorded_path(path), "clonings": 1}
    path = out / "demos" / f"{variant.name}.npz"
    record_path = path.with_suffix(".json")
    if not (path.exists() and record_path.exists()):
        start = time.perf_counter()
        if variant.kind == "dart":
            result = dart(TASK, variant.reg, n, rounds(), variant.sigma, seed=0, progress=progress)
        else:
            result = dagger(TASK, variant.reg, n, rounds(), seed=0, progress=progress)
        record = {"rounds": result.rounds, "expert_queries": result.expert_queries,
                  "expert_seconds": result.expert_seconds, "clonings": len(result.rounds),
                  "wall_time_s": time.perf_counter() - start}
        result.demos.save(path)
        record_path.write_text(json.dumps(record, indent=1))
    return Demos.load(path, task=TASK, samples=n), {"source": recorded_path(path), **json.loads(record_path.read_text())}


def cloned_policy(variant: Variant, demos: Demos, seed: int, checkpoints: Path):
    """The policy cloned on the variant's data with ``seed`` (settings of :func:`cloning_config`). A hand-set
    data set goes through :func:`pretrained_policy` (the shipped checkpoints of seeds 0-2 are reused); a DART
    or DAgger one is cloned here and kept as ``checkpoints/NAME_seedS.pt``."""
    cfg = cloning_config(variant.reg)
    if variant.kind == "hand-set":
        return pretrained_policy(variant.reg, demos, "state", seed, cfg, checkpoints)
    path = checkpoints / f"{variant.name}_seed{seed}.pt"
    try:
        return load_checkpoint(path, **asdict(cfg))
    except CheckpointError:
        policy, _ = pretrain(demos, cfg, seed=seed, progress=False)
        save_checkpoint(policy, path)
        return load_checkpoint(path)


@dataclass(frozen=True)
class PreRLJob:
    """One variant and seed as a job of the grid runner (:class:`~vdtutorial.runner.grid.GridJob`): clone on the
    variant's data set (made first, by :func:`beyond`) and score the mean action before RL. Its state file holds
    the one row and the settings it was made with, so a rerun finds it finished, and a rerun with other settings
    stops with the runner's :class:`~vdtutorial.runner.resume.ResumeError` rather than mixing results."""

    variant: Variant
    seed: int
    out: Path
    state_dir: Path

    @property
    def name(self) -> str:
        return f"{self.variant.name}_seed{self.seed}"

    @property
    def state_path(self) -> Path:
        return self.state_dir / f"{self.name}.pt"

    @property
    def csv_path(self) -> Path:
        return self.state_dir / f"{self.name}.csv"

    @property
    def settings(self) -> dict:
        return {"experiment": "beyond", "variant": asdict(self.variant), "seed": self.seed, "samples": samples(),
                "rounds": rounds(), "episodes": pre_rl_episodes(), "num_envs": NUM_ENVS,
                "pretrain_config": asdict(cloning_config(self.variant.reg))}

    @property
    def rows_expected(self) -> int:
        return 1

    @property
    def env_steps(self) -> int:
        return pre_rl_episodes() * EPISODE_STEPS

    def tags(self) -> dict:
        return {"label": self.variant.label, "kind": self.variant.kind, "method": self.variant.reg,
                "sigma": self.variant.sigma, "seed": self.seed}

    def summary(self, rows: list[dict]) -> str:
        return f"{rows[0]['successes']:.3g} successes per 200 steps before RL"

    def compute(self):
        start = time.perf_counter()
        demos, _ = data_set(self.variant, self.out)
        policy = cloned_policy(self.variant, demos, self.seed, self.out / "checkpoints")
        if self.variant.reg == "vd":
            policy.prune_()
        score = mean_action_successes(policy, TASK, self.seed, pre_rl_episodes(), NUM_ENVS)
        rows = [{**score, "success_rate": score["successes"] / max(score["trajectories"], 1e-12)}]
        save_finished_rows(self.state_path, self.settings, rows, time.perf_counter() - start)
        yield {"env_steps": self.env_steps}
        return rows


def _interval(values) -> dict:
    mean, low, high = mean_band(np.asarray(values, dtype=np.float64)[:, None])
    return {"mean": float(mean[0]), "low": float(low[0]), "high": float(high[0]), "n": len(values)}


def comparisons(rows: list[dict]) -> list[dict]:
    """Per regulariser: does DART beat the poor Sigma it started from; does it match the best hand-set
    Sigma (the paper's three, best by its own mean, which favours the hand-set side); what did DAgger buy
    over the best hand-set Sigma and over the paper's 0.5. Welch intervals, Bonferroni-corrected."""
    by_label: dict[str, list[float]] = {}
    for row in rows:
        by_label.setdefault(row["label"], []).append(row["successes"])
    pairs = []
    for reg in ("vd", "l2"):
        hand = {s: Variant("hand-set", reg, s).label for s in (*HAND_SET, TOO_LARGE)}
        best = max(HAND_SET, key=lambda s: np.mean(by_label[hand[s]]))
        for start in DART_STARTS:
            learned = Variant("dart", reg, start).label
            pairs += [("learned noise beats the poor Sigma it started from", learned, hand[start]),
                      ("learned noise against the best hand-set Sigma", learned, hand[best])]
        pairs += [("DAgger against the best hand-set Sigma", Variant("dagger", reg).label, hand[best]),
                  ("DAgger against the paper's Sigma=0.5", Variant("dagger", reg).label, hand[0.5])]
    confidence = 1 - (1 - CONFIDENCE) / len(pairs)
    out = []
    for question, a, b in pairs:
        estimate, low, high = welch_interval(by_label[a], by_label[b], confidence)
        out.append({"question": question, "a": a, "b": b, "measure": "pre-RL successes per 200 steps (mean action)",
                    "estimate": estimate, "low": low, "high": high, "confidence": confidence,
                    "reading": {"confirmed": "a above b", "contradicted": "a below b",
                                "not confirmed": "not distinguishable at this many seeds"}[verdict(low, high, 1)]})
    return out


def plot(rows: list[dict], made: dict[str, dict]) -> Figure:
    """Left: pre-RL successes per data set (mean and uncorrected 95% t-interval over seeds). Right:
    DART's learned Sigma per joint (the estimate of its last policy) against the hand-set values."""
    fig = Figure(figsize=(11, 4), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(1.6, 1))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    for i, label in enumerate(labels):
        band = _interval([r["successes"] for r in rows if r["label"] == label])
        colour = "tab:blue" if label.startswith(METHOD_LABELS["vd"]) else "tab:orange"
        left.errorbar(band["mean"], i, xerr=[[band["mean"] - band["low"]], [band["high"] - band["mean"]]],
                      fmt="o", color=colour, capsize=3)
    left.set_yticks(range(len(labels)), labels, fontsize=8)
    left.invert_yaxis()
    left.set_xlabel("pre-RL successes per 200 steps (mean action; 95% t-interval over seeds)", fontsize=9)
    left.grid(alpha=0.3)
    joints = np.arange(1, 7)
    for name, record in made.items():
        if "next_sigma_per_joint" in record.get("rounds", [{}])[-1]:
            right.plot(joints, record["rounds"][-1]["next_sigma_per_joint"], marker="o", label=name)
    for s in (*HAND_SET, TOO_LARGE):
        right.axhline(s, color="gray", lw=0.8, ls=":")
    right.set_yscale("log")
    right.set_xlabel("joint", fontsize=9)
    right.set_ylabel("Sigma (rad); dotted: hand-set values", fontsize=9)
    right.set_title("DART's learned Sigma per joint", fontsize=10)
    right.legend(fontsize=7)
    return fig


def beyond(seeds=None, out=None, workers: int = 1, progress: bool | None = None, backend: str = "local",
           address: str | None = None, restart: bool = False) -> dict:
    """The experiment (module docstring); returns its JSON record. The data sets are made here, one after
    the other; the runs are a grid (:func:`~vdtutorial.runner.grid.run_grid`: ``workers``, ``backend``,
    ``address``, ``restart``, ``progress``), their states in ``out/runs``.

    Files in ``out`` (default ``runs/beyond``; the shipped results in ``data/results/beyond``): ``demos/`` (the
    data sets made here, with each DART/DAgger round's record beside it), ``runs/`` (the runs' states), ``checkpoints/``,
    ``beyond.csv.gz``, ``beyond.png`` and ``beyond.json``.

    Resumable: the data sets and checkpoints are files made once, and the runs are a grid of the runner
    (:class:`PreRLJob`, :func:`~vdtutorial.runner.grid.run_grid`) with a state file each; running the same command
    again reads what is there and computes the rest. The RL stage (TRPO at 1e5 steps from these policies) is not run by this
    module (see ``RL_STAGE``).
    """
    seeds = tuple(budget((0, 1, 2, 3, 4), (0, 1)) if seeds is None else seeds)
    out = Path(out) if out is not None else default_out("beyond")
    start = time.perf_counter()
    made = {}
    for variant in variants():  # data sets first, one at a time: later runs only read them
        _, made[variant.label] = data_set(variant, out, bool(progress))
    state_dir = (out / "runs").resolve()
    jobs = [PreRLJob(v, s, out.resolve(), state_dir) for v in variants() for s in seeds]
    results = run_grid("beyond", jobs, workers, backend, address, restart, progress)
    rows = [row for result in results for row in result["rows"]]
    write_csv(results_file(out, "beyond"), rows)
    plot(rows, made).savefig(out / "beyond.png", dpi=110)
    per_label = {label: {q: _interval([r[q] for r in rows if r["label"] == label])
                         for q in ("successes", "trajectories", "success_rate")}
                 for label in dict.fromkeys(r["label"] for r in rows)}
    cost = {label: {"expert_queries": samples(), "clonings": data["clonings"],
                    "expert_seconds": data.get("expert_seconds")} for label, data in made.items()}
    record = {"experiment": "beyond", "command": experiment_command("beyond", seeds=seeds, workers=workers,
                                                                    out=out if out != default_out("beyond") else None),
              "quick": is_quick(), "task": TASK, "obs_mode": "state", "seeds": list(seeds), "samples": samples(),
              "rounds": rounds(), "dagger_beta": BETA, "pre_rl_episodes": pre_rl_episodes(), "num_envs": NUM_ENVS,
              "pretrain_config": {reg: asdict(cloning_config(reg)) for reg in ("vd", "l2")},
              "wall_time_s": time.perf_counter() - start, "rl_stage": RL_STAGE,
              "data_sets": made, "cost": cost, "pre_rl": per_label, "comparisons": comparisons(rows),
              "versions": {"vdtutorial": vdtutorial.__version__, "torch": torch.__version__,
                           "python": sys.version.split()[0]}}
    (out / "beyond.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def format_summary(record: dict) -> str:
    """The pre-RL scores and the comparisons of a :func:`beyond` record, a line each."""
    lines = [f"{label:>28}: {band['successes']['mean']:.2f} successes per 200 steps before RL "
             f"(95% interval {band['successes']['low']:.2f} to {band['successes']['high']:.2f}, {band['successes']['n']} seeds); "
             f"{record['cost'][label]['clonings']} cloning(s), {record['cost'][label]['expert_queries']} expert labels"
             for label, band in record["pre_rl"].items()]
    lines += [f"{c['question']} ({c['a']} - {c['b']}): {c['estimate']:+.2f} ({c['confidence']:.1%} interval "
              f"{c['low']:+.2f} to {c['high']:+.2f}): {c['reading']}" for c in record["comparisons"]]
    return "\n".join(lines)
