"""Beyond the paper: learned demonstration noise (DART) and DAgger beside the hand-set Sigma.

The paper's Section VI asks for "techniques for learning appropriate expert noise from the data" and calls
DAgger "computationally quite expensive". This experiment measures both on reaching, in state mode, at an
equal number of expert labels (``samples``, Fig. 4's 8000): the paper's hand-set Sigma 0.05, 0.25 and 0.5
and a too-large ``TOO_LARGE``; DART (:mod:`vdtutorial.beyond.dart`) from a poor start (``DART_STARTS``); DAgger
(:mod:`vdtutorial.beyond.dagger`), round 0 noise-free; each cloned with VD and with L2 (DART's and DAgger's rounds
clone with the regulariser they are measured with). A data set is made once (data seed 0) and shared by the
seeds; a seed replicates the cloning and the RL stage.

Two stages per data set and seed, jobs of one resumable grid: before RL (:class:`PreRLJob`), the pruned
mean action scored as TRPO counts an iteration (:func:`vdtutorial.experiments.evaluation.mean_action_successes`); the
RL stage (:class:`RLJob`), TRPO with the paper's settings from that clone, with the figures' start sigma and
pruning (:func:`~vdtutorial.experiments.runs.finetune_steps`), for ``rl_steps`` env steps. Comparisons:
before RL, differences of means over seeds with Welch intervals, Bonferroni-corrected (:func:`comparisons`);
after it, the figures' effects (:mod:`vdtutorial.experiments.effects`: final level and area under the curve
on every measure of :mod:`~vdtutorial.experiments.measures`, Holm-corrected). Per data set the expert
queries, seconds in the expert and clonings are counted (:func:`dagger_cost` says what DAgger's bought).

Taught in chapter 09.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure

import vdtutorial
from vdtutorial.beyond.dagger import BETA, dagger
from vdtutorial.beyond.dart import dart
from vdtutorial.beyond.imitation_rounds import cloning_config
from vdtutorial.demos import Demos, demo_path, generate_demos
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.curves import CONFIDENCE, mean_band, smooth_window
from vdtutorial.experiments.effects import MATERIALITY, Claim, per_run, run_summaries, verdict, welch_interval
from vdtutorial.experiments.evaluation import EPISODE_STEPS, mean_action_successes
from vdtutorial.experiments.measures import MEASURES, measures_of
from vdtutorial.experiments.plots import figure_title, save_png
from vdtutorial.experiments.results import default_out, derive, experiment_command
from vdtutorial.experiments.pipeline import pretrained_policy, ready_for_rl
from vdtutorial.experiments.runs import CHECKPOINT_EVERY, NUM_ENVS, default_trpo_config, finetune_steps, run_settings
from vdtutorial.methods import METHOD_LABELS, method
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner import SavedInStateDir, read_rows, results_file, run_grid, write_csv
from vdtutorial.runner.resume import save_finished_rows
from vdtutorial.experiments.paths import recorded_path
from vdtutorial.settings import budget, is_quick

TASK = "reach"
#: Sigma values of the paper's Fig. 6, the hand-set ones.
HAND_SET = (0.05, 0.25, 0.5)
#: A Sigma larger than any of the paper's: the arm's step is at most pi/5 = 0.63 rad per joint, so noise of
#: 1 rad per joint drowns the expert's own motion.
TOO_LARGE = 1.0
#: DART's poor starts: the smallest hand-set Sigma and the too-large one.
DART_STARTS = (0.05, TOO_LARGE)
#: The ``stage`` column of the experiment's rows: the score before RL, or an iteration of the RL stage.
PRE_RL, RL = "pre-RL", "RL"
#: The readings of a comparison's verdict (a against b, in the measure's better direction).
READINGS = {
    "confirmed": "a better than b",
    "contradicted": "a worse than b",
    "not confirmed": "not distinguishable at this many seeds",
    "negligible": f"a and b differ by less than {MATERIALITY:.0%} of b's level",
}


def samples() -> int:
    """Expert labels per data set: 8000 (quick mode: 300)."""
    return budget(8000, 300)


def rounds() -> int:
    """Rounds of DART and DAgger: 4 of 2000 labels (quick mode: 3 of 100)."""
    return budget(4, 3)


def rl_steps() -> int:
    """RL env steps per run: the issue's 1e5 (quick mode: 1000, five iterations). ``--steps 300000`` extends the
    finished runs to the paper's budget (a run's budget is not one of its settings)."""
    return budget(100_000, 1_000)


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
    return [
        v
        for reg in ("vd", "l2")
        for v in (
            *(Variant("hand-set", reg, s) for s in (*HAND_SET, TOO_LARGE)),
            *(Variant("dart", reg, s) for s in DART_STARTS),
            Variant("dagger", reg),
        )
    ]


def data_set_path(variant: Variant, out: Path) -> Path:
    """Where the variant's data set is: a hand-set one is the shipped file when there is one of this size,
    else (like DART's and DAgger's) a file of ``out/demos``."""
    if variant.kind == "hand-set":
        shipped = demo_path(TASK, samples(), variant.sigma, 0)
        return shipped if shipped.exists() else demo_path(TASK, samples(), variant.sigma, 0, root=out)
    return out / "demos" / f"{variant.name}.npz"


def data_set(variant: Variant, out: Path, progress: bool = False) -> tuple[Demos, dict]:
    """The variant's data set (:func:`data_set_path`) and how it was made (rounds, expert time), made once."""
    n, path = samples(), data_set_path(variant, out)
    if variant.kind == "hand-set":
        if not path.exists():
            generate_demos(TASK, n, variant.sigma, 0, progress).save(path)
        return Demos.load(path, task=TASK, samples=n), {"source": recorded_path(path), "clonings": 1}
    record_path = path.with_suffix(".json")
    if not (path.exists() and record_path.exists()):
        start = time.perf_counter()
        if variant.kind == "dart":
            result = dart(TASK, variant.reg, n, rounds(), variant.sigma, seed=0, progress=progress)
        else:
            result = dagger(TASK, variant.reg, n, rounds(), seed=0, progress=progress)
        record = {
            "rounds": result.rounds,
            "expert_queries": result.expert_queries,
            "expert_seconds": result.expert_seconds,
            "clonings": len(result.rounds),
            "wall_time_s": time.perf_counter() - start,
        }
        result.demos.save(path)
        record_path.write_text(json.dumps(record, indent=1))
    return Demos.load(path, task=TASK, samples=n), {
        "source": recorded_path(path),
        **json.loads(record_path.read_text()),
    }


def cloned_policy(variant: Variant, demos: Demos, seed: int, out: Path):
    """The policy cloned on the variant's data with ``seed`` (settings of :func:`cloning_config`), looked up or
    made by :func:`pretrained_policy` in ``out/checkpoints`` (a hand-set set's shipped checkpoints of seeds 0-2
    are reused; a DART or DAgger set's are named after its file). The RL stage starts from this checkpoint."""
    return pretrained_policy(
        variant.reg, demos, "state", seed, cloning_config(variant.reg), out, source=data_set_path(variant, out)
    )


def _tags(variant: Variant, seed: int, stage: str) -> dict:
    return {
        "label": variant.label,
        "kind": variant.kind,
        "method": variant.reg,
        "sigma": variant.sigma,
        "seed": seed,
        "stage": stage,
    }


@dataclass(frozen=True)
class PreRLJob(SavedInStateDir):
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
    def settings(self) -> dict:
        return {
            "experiment": "beyond",
            "variant": asdict(self.variant),
            "seed": self.seed,
            "samples": samples(),
            "rounds": rounds(),
            "episodes": pre_rl_episodes(),
            "num_envs": NUM_ENVS,
            "pretrain_config": asdict(cloning_config(self.variant.reg)),
        }

    @property
    def rows_expected(self) -> int:
        return 1

    @property
    def env_steps(self) -> int:
        return pre_rl_episodes() * EPISODE_STEPS

    def tags(self) -> dict:
        return _tags(self.variant, self.seed, PRE_RL)

    def summary(self, rows: list[dict]) -> str:
        return f"{rows[0]['successes']:.3g} successes per 200 steps before RL"

    def compute(self):
        start = time.perf_counter()
        demos, _ = data_set(self.variant, self.out)
        policy = cloned_policy(self.variant, demos, self.seed, self.out)
        policy = ready_for_rl(self.variant.reg, policy)
        score = mean_action_successes(policy, TASK, self.seed, pre_rl_episodes(), NUM_ENVS)
        rows = [{**score, "success_rate": score["successes"] / max(score["trajectories"], 1e-12)}]
        save_finished_rows(self.state_path, self.settings, rows, time.perf_counter() - start)
        yield {"env_steps": self.env_steps}
        return rows


@dataclass(frozen=True)
class RLJob(SavedInStateDir):
    """One variant and seed's RL stage as a grid job: TRPO with the paper's settings (:func:`default_trpo_config`)
    for ``steps`` env steps from the policy cloned on the variant's data set (:func:`cloned_policy`'s checkpoint),
    with the start sigma and, for VD, the pruning of the figures' runs
    (:func:`~vdtutorial.experiments.pipeline.finetune_policy`). The run is that of
    :func:`~vdtutorial.experiments.runs.finetune_steps`: its state saved every ``checkpoint_every`` iterations, a
    rerun continues it to the rows of an uninterrupted run, a larger ``steps`` extends it. ``start_sigma``: the
    sigma RL starts from (an :class:`~vdtutorial.experiments.initial_sigma.InitialSigma` spelling; None: the
    figures')."""

    variant: Variant
    seed: int
    steps: int
    out: Path
    state_dir: Path
    checkpoint_every: int = CHECKPOINT_EVERY
    start_sigma: str | None = None

    @property
    def pretrain_config(self) -> PretrainConfig:
        """The figures' pre-training settings (:func:`default_config`), with ``start_sigma`` if one is given."""
        config = default_config(self.variant.reg)
        return config if self.start_sigma is None else replace(config, initial_sigma=self.start_sigma)

    @property
    def name(self) -> str:
        return f"rl_{self.variant.name}_seed{self.seed}"

    @property
    def settings(self) -> dict:
        """What :func:`~vdtutorial.experiments.runs.finetune_steps` saves with the run (its run_settings)."""
        path = data_set_path(self.variant, self.out)
        return run_settings(
            self.variant.reg,
            TASK,
            Demos.load(path, task=TASK).meta,
            "state",
            self.seed,
            NUM_ENVS,
            self.pretrain_config,
            default_trpo_config(),
            path,
        )

    @property
    def rows_expected(self) -> int:
        return math.ceil(self.steps / default_trpo_config().steps_per_iter)

    @property
    def env_steps(self) -> int:
        return self.rows_expected * default_trpo_config().steps_per_iter

    def tags(self) -> dict:
        return _tags(self.variant, self.seed, RL)

    def summary(self, rows: list[dict]) -> str:
        return f"{len(rows)} TRPO iterations, last {rows[-1]['successes']:.3g} successes per 200 steps"

    def compute(self):
        _, rows = yield from finetune_steps(
            self.variant.reg,
            TASK,
            data_set_path(self.variant, self.out),
            "state",
            self.seed,
            self.steps,
            pretrain_config=self.pretrain_config,
            checkpoints_root=self.out,
            state_path=self.state_path,
            checkpoint_every=self.checkpoint_every,
        )
        return rows


def _interval(values) -> dict:
    mean, low, high = mean_band(np.asarray(values, dtype=np.float64)[:, None])
    return {"mean": float(mean[0]), "low": float(low[0]), "high": float(high[0]), "n": len(values)}


def _questions(reg: str, level) -> list[tuple[str, str, str]]:
    """The experiment's questions for one regulariser as (question, a, b) labels; ``level(label)`` ranks the
    paper's three hand-set Sigma values to pick the best one (by its own mean, which favours the hand-set side)."""
    hand = {s: Variant("hand-set", reg, s).label for s in (*HAND_SET, TOO_LARGE)}
    best = max(HAND_SET, key=lambda s: level(hand[s]))
    pairs = []
    for start in DART_STARTS:
        learned = Variant("dart", reg, start).label
        pairs += [
            ("learned noise beats the poor Sigma it started from", learned, hand[start]),
            ("learned noise against the best hand-set Sigma", learned, hand[best]),
        ]
    dagger_label = Variant("dagger", reg).label
    return pairs + [
        ("DAgger against the best hand-set Sigma", dagger_label, hand[best]),
        ("DAgger against the paper's Sigma=0.5", dagger_label, hand[0.5]),
    ]


def comparisons(rows: list[dict]) -> list[dict]:
    """Before RL, per regulariser: does DART beat the poor Sigma it started from; does it match the best hand-set
    Sigma; what did DAgger buy over the best hand-set Sigma and over the paper's 0.5 (:func:`_questions`). Welch
    intervals of pre-RL successes, Bonferroni-corrected."""
    by_label: dict[str, list[float]] = {}
    for row in rows:
        by_label.setdefault(row["label"], []).append(row["successes"])
    pairs = [pair for reg in ("vd", "l2") for pair in _questions(reg, lambda label: np.mean(by_label[label]))]
    confidence = 1 - (1 - CONFIDENCE) / len(pairs)
    out = []
    for question, a, b in pairs:
        estimate, low, high = welch_interval(by_label[a], by_label[b], confidence)
        out.append(
            {
                "question": question,
                "a": a,
                "b": b,
                "measure": "pre-RL successes per 200 steps (mean action)",
                "estimate": estimate,
                "low": low,
                "high": high,
                "confidence": confidence,
                "reading": {
                    "confirmed": "a above b",
                    "contradicted": "a below b",
                    "not confirmed": "not distinguishable at this many seeds",
                }[verdict(low, high, 1)],
            }
        )
    return out


def rl_claims(rows: list[dict], window: int) -> tuple[Claim, ...]:
    """The questions of :func:`comparisons` asked of the RL curves, each at the final level and over the whole
    run (area under the curve); the best hand-set Sigma is the one with the highest final level of successes."""
    final = {
        label: float(run_summaries(group, "final", window).mean())
        for label, group in per_run(rows, "successes").items()
    }
    kinds = {"final": "final level", "auc": "area under the curve"}
    return tuple(
        Claim("beyond", f"{question}: {a} vs {b} ({kinds[kind]})", kind, a, b)
        for reg in ("vd", "l2")
        for question, a, b in _questions(reg, final.__getitem__)
        for kind in kinds
    )


def rl_stage(rows: list[dict], seeds, steps: int, configs: dict[str, PretrainConfig]) -> tuple[Figure, dict]:
    """The RL curves' figure (one panel per measure) and record: each curve's final point and the claims of
    :func:`rl_claims` on every measure, as the figures derive them (:func:`~vdtutorial.experiments.results.derive`:
    95% Welch intervals, verdicts and Holm-corrected verdicts), each read in words (``reading``, of the Holm
    verdict). ``configs``: the RL runs' pre-training settings per regulariser, for the record."""
    window = smooth_window()
    figure, summary = _rl_derive(rows, len(seeds), steps, window)
    return figure, {
        "steps": steps,
        "window": window,
        "metric": "successes",
        "measures": list(measures_of("successes")),
        "trpo_config": asdict(default_trpo_config()),
        "pretrain_config": {reg: asdict(config) for reg, config in configs.items()},
        **summary,
    }


def _rl_derive(rows: list[dict], seeds: int, steps: int, window: int) -> tuple[Figure, dict]:
    """What the RL rows say (:func:`rl_stage`): the figure, the final points and the claims, each read in words."""
    title = figure_title(
        "Beyond the paper: TRPO from hand-set Sigma, DART and DAgger (reaching)", "state", steps, seeds
    )
    _, figure, summary = derive("beyond", rows, "successes", window, title, rl_claims(rows, window))
    for effect in summary["claims"]:
        effect["reading"] = READINGS[effect["holm_verdict"]]
    return figure, summary


def rederive_beyond(folder) -> dict:
    """Re-write the RL part of a :func:`beyond` record (figure, final points, claims and their readings, what DAgger's
    work bought) from its rows, without running anything: ``python -m vdtutorial rederive data/results/beyond``
    after the analysis changed. The pre-RL comparisons and the data sets' costs are kept as recorded."""
    folder = Path(folder)
    record = json.loads((folder / "beyond.json").read_text())
    rows = [row for row in read_rows(results_file(folder, "beyond")) if row["stage"] == RL]
    rl = record["rl"]
    figure, summary = _rl_derive(rows, len(record["seeds"]), rl["steps"], rl["window"])
    save_png(figure, folder / "beyond_rl.png", 110)
    record["rl"] = {**rl, **summary}
    record["dagger_cost"] = dagger_cost(record["cost"], record["comparisons"], summary["claims"], rl["steps"])
    (folder / "beyond.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def dagger_cost(cost: dict, pre: list[dict], rl: list[dict], steps: int) -> list[dict]:
    """What DAgger's extra work bought, per regulariser: its expert queries, clonings and seconds in the expert
    beside the best hand-set Sigma's once-generated set, and the difference it made before RL (Bonferroni) and
    after ``steps`` RL steps (successes: final level and area under the curve, Holm), with a sentence saying so."""
    out = []
    for reg in ("vd", "l2"):
        label = Variant("dagger", reg).label
        before = next(c for c in pre if c["a"] == label and c["question"] == "DAgger against the best hand-set Sigma")
        after = {
            c["measure"]: c
            for c in rl
            if c["a"] == label
            and c["metric"] == "successes"
            and c["text"].startswith("DAgger against the best hand-set Sigma")
        }
        made = cost[label]
        sentence = (
            f"{label}: {made['expert_queries']} expert queries ({made['expert_seconds']:.0f} s in the expert) "
            f"and {made['clonings']} clonings, against one cloning of {before['b']}'s once-generated "
            f"{cost[before['b']]['expert_queries']} labels; before RL {before['estimate']:+.2f} successes per "
            f"200 steps ({before['reading']})"
        )
        if after:
            sentence += "; after {:g} RL steps{}".format(
                steps,
                "".join(
                    f", {kind} {after[kind]['estimate']:+.2f} against {after[kind]['b']} ({after[kind]['reading']})"
                    for kind in ("final", "auc")
                ),
            )
        out.append({"dagger": label, **made, "before_rl": before, "after_rl": after, "statement": sentence})
    return out


def plot(rows: list[dict], made: dict[str, dict]) -> Figure:
    """Left: pre-RL successes per data set (mean and uncorrected 95% t-interval over seeds). Right:
    DART's learned Sigma per joint (the estimate of its last policy) against the hand-set values."""
    fig = Figure(figsize=(11, 4), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(1.6, 1))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    for i, label in enumerate(labels):
        band = _interval([r["successes"] for r in rows if r["label"] == label])
        colour = method(next(r["method"] for r in rows if r["label"] == label)).colour
        left.errorbar(
            band["mean"],
            i,
            xerr=[[band["mean"] - band["low"]], [band["high"] - band["mean"]]],
            fmt="o",
            color=colour,
            capsize=3,
        )
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


def beyond(
    seeds=None,
    steps: int | None = None,
    out=None,
    workers: int = 1,
    progress: bool | None = None,
    backend: str = "local",
    address: str | None = None,
    restart: bool = False,
    state_dir=None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    start_sigma: str | None = None,
) -> dict:
    """The experiment (module docstring, "Two stages per data set and seed"); returns its JSON record. The data sets
    are made here, one after
    the other; the runs are a grid (:func:`~vdtutorial.runner.grid.run_grid`: ``workers``, ``backend``,
    ``address``, ``restart``, ``progress``): per variant and seed a :class:`PreRLJob` and an :class:`RLJob` of
    ``steps`` env steps (default :func:`rl_steps`; RL starts from ``start_sigma``, default the figures' start
    sigma), their states in ``state_dir`` (default ``out/runs``).

    Files in ``out`` (default ``runs/beyond``; the shipped results in ``data/results/beyond``): ``demos/`` (the
    data sets made here, with each DART/DAgger round's record beside it), ``runs/``, ``checkpoints/``,
    ``beyond.csv.gz`` (all rows, ``stage`` pre-RL or RL), ``beyond.png`` (before RL, and DART's learned Sigma),
    ``beyond_rl.png`` (the RL curves) and ``beyond.json``.

    Resumable: the data sets and checkpoints are files made once, and every run has a state file; running the
    same command again reads what is there and computes the rest, and a larger ``steps`` extends the RL runs.
    """
    seeds = tuple(budget((0, 1, 2, 3, 4), (0, 1)) if seeds is None else seeds)
    steps = rl_steps() if steps is None else steps
    out = Path(out) if out is not None else default_out("beyond")
    start = time.perf_counter()
    made = {}
    for variant in variants():  # data sets first, one at a time: later runs only read them
        _, made[variant.label] = data_set(variant, out, bool(progress))
    state_dir = Path(state_dir).resolve() if state_dir is not None else (out / "runs").resolve()
    jobs = [PreRLJob(v, s, out.resolve(), state_dir) for v in variants() for s in seeds] + [
        RLJob(v, s, steps, out.resolve(), state_dir, checkpoint_every, start_sigma) for v in variants() for s in seeds
    ]
    results = run_grid("beyond", jobs, workers, backend, address, restart, progress)
    rows = [row for result in results for row in result["rows"]]
    write_csv(results_file(out, "beyond"), rows)
    pre = [row for row in rows if row["stage"] == PRE_RL]
    save_png(plot(pre, made), out / "beyond.png", 110)
    configs = {job.variant.reg: job.pretrain_config for job in jobs if isinstance(job, RLJob)}
    rl_figure, rl = rl_stage([row for row in rows if row["stage"] == RL], seeds, steps, configs)
    save_png(rl_figure, out / "beyond_rl.png", 110)
    per_label = {
        label: {
            q: _interval([r[q] for r in pre if r["label"] == label])
            for q in ("successes", "trajectories", "success_rate")
        }
        for label in dict.fromkeys(r["label"] for r in pre)
    }
    cost = {
        label: {"expert_queries": samples(), "clonings": data["clonings"], "expert_seconds": data.get("expert_seconds")}
        for label, data in made.items()
    }
    pre_comparisons = comparisons(pre)
    record = {
        "experiment": "beyond",
        "command": experiment_command(
            "beyond", seeds=seeds, steps=steps, workers=workers, out=out if out != default_out("beyond") else None
        ),
        "quick": is_quick(),
        "task": TASK,
        "obs_mode": "state",
        "seeds": list(seeds),
        "samples": samples(),
        "rounds": rounds(),
        "dagger_beta": BETA,
        "pre_rl_episodes": pre_rl_episodes(),
        "num_envs": NUM_ENVS,
        "pretrain_config": {reg: asdict(cloning_config(reg)) for reg in ("vd", "l2")},
        "wall_time_s": time.perf_counter() - start,  # this invocation's; a resumed run's cost is in the next two
        "run_seconds": sum(result["seconds"] for result in results),  # every job's, over all invocations
        "data_set_seconds": sum(data.get("wall_time_s", 0.0) for data in made.values()),  # DART's, DAgger's
        "data_sets": made,
        "cost": cost,
        "pre_rl": per_label,
        "comparisons": pre_comparisons,
        "rl": rl,
        "dagger_cost": dagger_cost(cost, pre_comparisons, rl["claims"], steps),
        "versions": {
            "vdtutorial": vdtutorial.__version__,
            "torch": torch.__version__,
            "python": sys.version.split()[0],
        },
    }
    (out / "beyond.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def _band(point: dict, digits: int = 2, feasible=(float("-inf"), float("inf"))) -> str:
    """Mean (interval), the interval clipped to the values the measure can take, as the figures' bands are."""
    low, high = max(point["low"], feasible[0]), min(point["high"], feasible[1])
    return f"{point['mean']:.{digits}f} ({low:.{digits}f} to {high:.{digits}f})"


def markdown_tables(record: dict) -> str:
    """The results page's two tables of a :func:`beyond` record (tests/test_beyond.py checks that the page holds
    them). First, per data set: what it cost (expert labels, clonings, seconds in the expert) and how its clones
    scored before RL and at the end of the RL stage on every measure (mean and 95% interval over seeds, clipped to
    the measure's possible values). Then each
    question of :func:`comparisons` with its difference a - b before RL (Bonferroni) and after RL on the paper's
    metric (final level and area under the curve, Holm), each with its verdict."""
    rl, measures = record["rl"], record["rl"]["measures"]
    names = {"successes": "successes", "success_rate": "success rate", "steps_per_trajectory": "steps per trajectory"}
    lines = [
        "| data set | expert labels | clonings | s in the expert | before RL: successes | "
        + " | ".join(f"after RL, {names.get(m, m)}" for m in measures)
        + " |",
        "|---|---|---|---|---|" + "---|" * len(measures),
    ]
    for label, before in record["pre_rl"].items():
        cost = record["cost"][label]
        seconds = "-" if cost["expert_seconds"] is None else f"{cost['expert_seconds']:.0f}"
        finals = [
            _band(rl["final_by_measure"][m][label], 3 if m == "success_rate" else 2, MEASURES[m].feasible)
            for m in measures
        ]
        lines.append(
            f"| {label} | {cost['expert_queries']} | {cost['clonings']} | {seconds} | "
            f"{_band(before['successes'], feasible=MEASURES['successes'].feasible)} | " + " | ".join(finals) + " |"
        )
    # the RL stage picks the best hand-set Sigma by its final level, the pre-RL stage by its pre-RL mean: b may differ
    after = {}
    for c in rl["claims"]:
        if c["metric"] == rl["metric"]:
            after[c["text"].split(":")[0], c["a"], c["measure"]] = c
    lines += [
        "",
        "| question | a | before RL: b | a - b | reading | after RL: b | final level: a - b | Holm | "
        "area: a - b | Holm |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in record["comparisons"]:
        final, auc = after[c["question"], c["a"], "final"], after[c["question"], c["a"], "auc"]
        cells = [
            c["question"],
            c["a"],
            c["b"],
            f"{c['estimate']:+.2f} ({c['low']:+.2f} to {c['high']:+.2f})",
            c["reading"],
            final["b"],
        ]
        for effect in (final, auc):
            cells += [
                f"{effect['estimate']:+.3g} ({effect['low']:+.3g} to {effect['high']:+.3g})",
                effect["holm_verdict"],
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_summary(record: dict) -> str:
    """The pre-RL scores and comparisons of a :func:`beyond` record, the RL stage's final levels and its claims on
    the paper's metric (every measure: the record's ``rl.claims``), and what DAgger's work bought, a line each."""
    lines = [
        f"{label:>28}: {band['successes']['mean']:.2f} successes per 200 steps before RL "
        f"(95% interval {band['successes']['low']:.2f} to {band['successes']['high']:.2f}, "
        f"{band['successes']['n']} seeds); "
        f"{record['cost'][label]['clonings']} cloning(s), {record['cost'][label]['expert_queries']} expert labels"
        for label, band in record["pre_rl"].items()
    ]
    lines += [
        f"{c['question']} ({c['a']} - {c['b']}): {c['estimate']:+.2f} ({c['confidence']:.1%} interval "
        f"{c['low']:+.2f} to {c['high']:+.2f}): {c['reading']}"
        for c in record["comparisons"]
    ]
    rl = record.get("rl")
    if rl is None:  # a record written before the RL stage existed
        return "\n".join(lines + ["no RL stage in this record"])
    lines += [
        f"{label:>28}: {final['mean']:.2f} successes per 200 steps after {rl['steps']:g} RL steps (final level, "
        f"95% band {final['low']:.2f} to {final['high']:.2f}, {final['seeds']} seeds)"
        for label, final in rl["final"].items()
    ]
    lines += [
        f"after RL, {c['text']}: {c['estimate']:+.3g} ({c['confidence']:.0%} interval {c['low']:+.3g} to "
        f"{c['high']:+.3g}, p {c['p_value']:.2g}): {c['reading']} (Holm)"
        for c in rl["claims"]
        if c["metric"] == rl["metric"]
    ]
    return "\n".join(lines + [entry["statement"] for entry in record["dagger_cost"]])
