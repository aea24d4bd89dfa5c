"""Our free choices, each tried: values the paper does not give, each changed alone, and whether the
VD-vs-L2 verdict moves.

The rows (:data:`CHOICES`): L2's coefficient (``PretrainConfig.l2``, 1e-4); the KL term's weight in VD's ELBO
(``kl_divisor``, the N dividing it: by default the training split's size, as eq. 3 reads) and its warm-up
(``beta_warmup``); the sigma L2's policy starts RL from (``initial_sigma``; the figures fit it to VD's predictive
spread). The likelihood's sigma, 0.3 (the sigma network's output, frozen while mu is cloned), is no row of its
own: the loss is sum (a - mu)^2 / (2 sigma^2) plus the regulariser, and Adam's steps do not change when a loss is
multiplied by a constant, so a sigma s weighs the regulariser as the default does times (s / 0.3)^2. A sigma of
0.1 is the L2 coefficient / 9 and the KL weight / 9; a sigma of 1.0 multiplies both by 11.1: those are the rows.

A row changes one value for the method it belongs to; the other method keeps the figures' settings. Every run is
Fig. 4's (reaching, 8000 demonstrations, Sigma 0.5, state mode) for :func:`rl_steps` env steps. Per row, VD
against L2 at the final level and over the whole run, Holm-corrected over all rows, beside the default's verdict.
A changed row pre-trains into its own checkpoint folder (a checkpoint's name holds neither ``l2`` nor
``beta_warmup``).

Taught in appendix A4.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch

import vdtutorial
from vdtutorial.experiments.checkpoints import default_config
from vdtutorial.experiments.curves import smooth_window
from vdtutorial.experiments.effects import Claim
from vdtutorial.experiments.jobs import Job, RunSpec
from vdtutorial.experiments.plots import figure_title, save_png
from vdtutorial.experiments.results import default_out, derive, experiment_command
from vdtutorial.experiments.runs import CHECKPOINT_EVERY, METRIC, NUM_ENVS, default_seeds, default_trpo_config
from vdtutorial.methods import METHOD_LABELS
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner import read_rows, results_file, run_grid, write_csv
from vdtutorial.settings import budget, data_dir, is_quick

TASK, SAMPLES, NOISE = "reach", 8000, 0.5
#: The training split of Fig. 4's data set holds 7101-7273 samples for seeds 0-2; the KL rows scale this N.
TRAIN_SPLIT = 7200
#: The row of the figures' own settings, whose VD and L2 runs every other row compares against.
DEFAULT = "default"


@dataclass(frozen=True)
class FreeChoice:
    """One row: ``change`` (PretrainConfig fields) applied to ``method``'s pre-training. ``choice``: what is
    changed; ``value``: the new value in words; ``default``: the figures' value in words."""

    name: str
    choice: str
    method: str
    change: dict
    value: str
    default: str

    def config(self) -> PretrainConfig:
        return replace(default_config(self.method), **self.change)

    @property
    def label(self) -> str:
        return f"{METHOD_LABELS[self.method]}, {self.choice} {self.value}"


CHOICES = (
    FreeChoice("l2_small", "L2 coefficient", "l2", {"l2": 1e-4 / 9}, "1.1e-5 (= likelihood sigma 0.1)", "1e-4"),
    FreeChoice("l2_large", "L2 coefficient", "l2", {"l2": 1e-4 / 0.09}, "1.1e-3 (= likelihood sigma 1.0)", "1e-4"),
    FreeChoice(
        "kl_weak",
        "KL weight",
        "vd",
        {"kl_divisor": 9 * TRAIN_SPLIT},
        "N = 64800, 1/9 (= likelihood sigma 0.1)",
        "N = training split",
    ),
    FreeChoice(
        "kl_strong",
        "KL weight",
        "vd",
        {"kl_divisor": round(0.09 * TRAIN_SPLIT)},
        "N = 648, x11.1 (= likelihood sigma 1.0)",
        "N = training split",
    ),
    FreeChoice(
        "no_warmup", "KL warm-up", "vd", {"beta_warmup": 0.0}, "none (beta = 1 from the start)", "30% of the epochs"
    ),
    FreeChoice("long_warmup", "KL warm-up", "vd", {"beta_warmup": 1.0}, "over all epochs", "30% of the epochs"),
    FreeChoice(
        "l2_sigma_paper",
        "L2's RL start sigma",
        "l2",
        {"initial_sigma": "0.3"},
        "the paper's fixed 0.3",
        "fitted to VD's spread",
    ),
    FreeChoice(
        "l2_sigma_demos",
        "L2's RL start sigma",
        "l2",
        {"initial_sigma": "demos"},
        "fitted to the demonstrations",
        "fitted to VD's spread",
    ),
)
CHOICE_NAMES = tuple(choice.name for choice in CHOICES)


def rl_steps() -> int:
    """RL env steps per run: the issue's 1e5 (quick mode: 1000, five iterations)."""
    return budget(100_000, 1_000)


@dataclass(frozen=True)
class _RowJob(Job):
    """A figure run (:class:`~vdtutorial.experiments.jobs.Job`) of one row, its files in the row's folders."""

    row: str = DEFAULT

    @property
    def name(self) -> str:
        return f"{self.row}/{self.spec.name}"


def _job(
    method: str,
    label: str,
    seed: int,
    steps: int,
    config: PretrainConfig,
    row: str,
    out: Path,
    state_dir: Path,
    checkpoint_every: int | None,
) -> Job:
    spec = RunSpec(method, TASK, SAMPLES, NOISE, seed, "state", steps, label)
    folder = state_dir / row
    return _RowJob(
        spec,
        folder / f"{spec.name}.pt",
        folder / f"{spec.name}.csv",
        data_dir().resolve(),
        (out / "checkpoints" / row).resolve(),
        config,
        default_trpo_config(),
        CHECKPOINT_EVERY if checkpoint_every is None else checkpoint_every,
        row=row,
    )


def jobs(names, seeds, steps: int, out: Path, state_dir: Path, checkpoint_every: int | None = None) -> list[Job]:
    """The default row's VD and L2 runs, and each named row's runs of the method it changes."""
    made = [
        _job(
            method,
            METHOD_LABELS[method],
            seed,
            steps,
            default_config(method),
            DEFAULT,
            out,
            state_dir,
            checkpoint_every,
        )
        for method in ("vd", "l2")
        for seed in seeds
    ]
    for choice in (c for c in CHOICES if c.name in names):
        made += [
            _job(
                choice.method, choice.label, seed, steps, choice.config(), choice.name, out, state_dir, checkpoint_every
            )
            for seed in seeds
        ]
    return made


def claims(names) -> tuple[Claim, ...]:
    """VD against L2 per row (final level, area under the curve): the default's, then each row's with its
    changed method in place of the default one."""
    pairs = [(DEFAULT, METHOD_LABELS["vd"], METHOD_LABELS["l2"])]
    for choice in (c for c in CHOICES if c.name in names):
        vd, l2 = (choice.label if choice.method == compared else METHOD_LABELS[compared] for compared in ("vd", "l2"))
        pairs.append((choice.name, vd, l2))
    kinds = {"final": "final level", "auc": "area under the curve"}
    return tuple(
        Claim("free_choices", f"[{row}] {vd} vs {l2} ({kinds[kind]})", kind, vd, l2)
        for row, vd, l2 in pairs
        for kind in kinds
    )


def table(effects: list[dict], names, out_command) -> list[dict]:
    """One entry per row and kind (final, auc), on the paper's metric: the VD - L2 estimate and interval, the
    verdict and the Holm verdict, the detectable difference, whether the Holm verdict is the default row's, and the
    command that makes the row (``out_command(name)``)."""
    metric = METRIC[TASK]
    by_text = {e["text"]: e for e in effects if e["metric"] == metric}
    rows, default_verdict = [], {}
    for row in (DEFAULT, *[c.name for c in CHOICES if c.name in names]):
        choice = next((c for c in CHOICES if c.name == row), None)
        for kind in ("final", "auc"):
            effect = next(e for text, e in by_text.items() if text.startswith(f"[{row}] ") and e["measure"] == kind)
            default_verdict.setdefault(kind, effect["holm_verdict"])
            rows.append(
                {
                    "row": row,
                    "choice": choice.choice if choice else "none (the figures' settings)",
                    "method": choice.method if choice else None,
                    "value": choice.value if choice else "",
                    "default": choice.default if choice else "",
                    "kind": kind,
                    "estimate": effect["estimate"],
                    "low": effect["low"],
                    "high": effect["high"],
                    "verdict": effect["verdict"],
                    "holm_verdict": effect["holm_verdict"],
                    "detectable": effect["detectable"],
                    "same_as_default": effect["holm_verdict"] == default_verdict[kind],
                    "command": out_command(row),
                }
            )
    return rows


def free_choices(
    names=CHOICE_NAMES,
    seeds=None,
    steps: int | None = None,
    out=None,
    workers: int = 2,
    progress: bool | None = None,
    backend: str = "local",
    address: str | None = None,
    restart: bool = False,
    state_dir=None,
    checkpoint_every: int | None = None,
) -> dict:
    """Run the default row and the rows ``names`` (:data:`CHOICES`) as one resumable grid and write
    ``free_choices.csv.gz``, ``free_choices.png`` (the curves, one panel per measure) and ``free_choices.json``
    (the :func:`table` and every claim on every measure) into ``out`` (default ``runs/free_choices``; the shipped
    results: ``data/results/free_choices``). Seeds: default :func:`~vdtutorial.experiments.runs.default_seeds`."""
    unknown = sorted(set(names) - set(CHOICE_NAMES))
    if unknown:
        raise ValueError(f"unknown free choice(s) {unknown}: choose from {list(CHOICE_NAMES)}")
    seeds = tuple(default_seeds() if seeds is None else seeds)
    steps = rl_steps() if steps is None else steps
    out = Path(out) if out is not None else default_out("free_choices")
    state_dir = Path(state_dir).resolve() if state_dir is not None else (out / "runs").resolve()
    start = time.perf_counter()
    grid = jobs(names, seeds, steps, out.resolve(), state_dir, checkpoint_every)
    results = run_grid("free_choices", grid, workers, backend, address, restart, progress)
    rows = [row for result in results for row in result["rows"]]
    out.mkdir(parents=True, exist_ok=True)
    write_csv(results_file(out, "free_choices"), rows)
    window = smooth_window()
    shown_out = out if out != default_out("free_choices") else None

    def command(row: str) -> str:
        chosen = () if row == DEFAULT else (row,)
        return experiment_command("free_choices", choices=chosen or None, seeds=seeds, steps=steps, out=shown_out)

    record = {
        "experiment": "free_choices",
        "command": experiment_command(
            "free_choices",
            choices=None if tuple(names) == CHOICE_NAMES else tuple(names),
            seeds=seeds,
            steps=steps,
            workers=workers,
            out=shown_out,
        ),
        "quick": is_quick(),
        "task": TASK,
        "samples": SAMPLES,
        "noise": NOISE,
        "obs_mode": "state",
        "seeds": list(seeds),
        "steps": steps,
        "window": window,
        "num_envs": NUM_ENVS,
        "choices": [asdict(c) for c in CHOICES if c.name in names],
        "pretrain_config": {m: asdict(default_config(m)) for m in ("vd", "l2")},
        "trpo_config": asdict(default_trpo_config()),
        "wall_time_s": time.perf_counter() - start,
        "versions": {
            "vdtutorial": vdtutorial.__version__,
            "torch": torch.__version__,
            "python": sys.version.split()[0],
        },
    }
    return _write_derived(out, record, rows, names, command)


def _write_derived(out: Path, record: dict, rows: list[dict], names, command) -> dict:
    """Add what the rows say to ``record`` (the claims on every measure and the :func:`table`, each row's command
    ``command(row)``), draw ``free_choices.png`` and write ``free_choices.json`` into ``out``."""
    title = figure_title(
        "Our free choices: VD and L2 with one pre-training value changed (reaching)",
        "state",
        record["steps"],
        len(record["seeds"]),
    )
    _, figure, summary = derive("free_choices", rows, METRIC[TASK], record["window"], title, claims(names))
    save_png(figure, out / "free_choices.png", 110)
    record.update(table=table(summary["claims"], names, command), **summary)
    (out / "free_choices.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def rederive_free_choices(folder) -> dict:
    """Re-write a :func:`free_choices` folder's figure, claims and table from its rows, without running anything
    (``python -m vdtutorial rederive data/results/free_choices`` after the analysis changed); each row keeps the
    command recorded for it."""
    folder = Path(folder)
    record = json.loads((folder / "free_choices.json").read_text())
    commands = {row["row"]: row["command"] for row in record["table"]}
    names = [choice["name"] for choice in record["choices"]]
    return _write_derived(folder, record, read_rows(results_file(folder, "free_choices")), names, commands.__getitem__)


def format_table(record: dict) -> str:
    """The record's table, a line per row and kind: VD - L2 on the paper's metric, the Holm verdict, and
    whether it is the default's."""
    return "\n".join(
        f"{r['choice']:>22} {r['value']:<42} {r['kind']:>5}: VD - L2 {r['estimate']:+8.2f} "
        f"({r['low']:+.2f} to {r['high']:+.2f}), Holm: {r['holm_verdict']}"
        + ("" if r["row"] == DEFAULT else ("; same as the default" if r["same_as_default"] else "; CHANGED"))
        for r in record["table"]
    )


def markdown_table(record: dict) -> str:
    """The record's table for the results page: a line per row, VD - L2 on the paper's metric at the final level
    and over the run (95% interval over seeds, Holm verdict), whether both verdicts are the default row's, and the
    command that makes the row."""
    lines = [
        "| row | what changes | value | final: VD - L2 | Holm | area: VD - L2 | Holm | "
        "verdicts as the default's | command |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    entries = {(r["row"], r["kind"]): r for r in record["table"]}
    for row in dict.fromkeys(r["row"] for r in record["table"]):
        final, auc = entries[row, "final"], entries[row, "auc"]
        method = f"{METHOD_LABELS[final['method']]}: " if final["method"] else ""
        value = f"{final['value']}; default {final['default']}" if final["value"] else "-"
        same = "-" if row == DEFAULT else "yes" if final["same_as_default"] and auc["same_as_default"] else "**no**"
        cells = [
            row,
            method + final["choice"],
            value,
            f"{final['estimate']:+.2f} ({final['low']:+.2f} to {final['high']:+.2f})",
            final["holm_verdict"],
            f"{auc['estimate']:+.2f} ({auc['low']:+.2f} to {auc['high']:+.2f})",
            auc["holm_verdict"],
            same,
            f"`{final['command']}`",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
