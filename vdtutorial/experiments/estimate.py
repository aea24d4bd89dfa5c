"""What a grid costs on N cores: an estimate of wall time from measured env steps per second.

A run is one task on one core (one torch thread, see :mod:`~vdtutorial.runner.backends`), so a
grid's wall time on ``cores`` cores is the time at which the last run ends when the runs, in the grid's
order, each start on the first core that is free (Ray and the local pool both hand out tasks that
way). A run lasts ``total_steps / steps_per_s`` seconds, plus ``pretrain_s[method]`` when its pre-trained
checkpoint is not shipped and must be made first, plus ``sigma_fit_s`` for every VD and L2 run, which
fits its start sigma before RL (``initial_sigma="spread"``, once per run; an L2 run's fit needs the VD
checkpoint, see :func:`run_seconds`). The expert's reference runs
take seconds and are left out. The rate is a parameter, to be measured (``python -m vdtutorial bench finetune`` gives
the rate of
one process on one core); it is the rate of one run *per core*, so on a machine whose cores slow each
other down (shared memory bandwidth) use the rate measured with all cores busy.

Taught in chapter 07.
"""

from __future__ import annotations

import heapq
from dataclasses import replace

from vdtutorial.demos import demo_path
from vdtutorial.experiments.checkpoints import RL_START_SIGMA, checkpoint_path
from vdtutorial.experiments.figures import FIGURES, figure_specs
from vdtutorial.experiments.jobs import RunSpec
from vdtutorial.methods import method


def makespan(seconds: list[float], cores: int) -> float:
    """When the last of the runs (``seconds`` each, in this order) ends, each run starting on the first
    free one of ``cores`` cores."""
    free = [0.0] * max(1, min(cores, len(seconds)))
    for duration in seconds:
        heapq.heappush(free, heapq.heappop(free) + duration)
    return max(free) if seconds else 0.0


def distinct_runs(names, seeds=(0, 1, 2), total_steps: int = 300_000, obs_mode: str = "rgbd") -> list[RunSpec]:
    """The runs of the figures ``names`` without the expert's, each once: figures that share a state folder
    (``--state-dir``) share their common runs (e.g. Fig. 5's and Fig. 6's 8000-sample, Sigma = 0.5 runs
    are Fig. 4's)."""
    specs = {}
    for name in names:
        for spec in figure_specs(name, seeds, total_steps, obs_mode):
            if spec.method != "expert":
                specs.setdefault(spec.name, spec)
    return list(specs.values())


def needs_pretraining(spec: RunSpec) -> bool:
    """Whether the run must pre-train first: a run of a method that pre-trains without a shipped checkpoint in
    ``data/``."""
    if not method(spec.method).pretrains:
        return False
    meta = {"task": spec.task, "samples": spec.samples, "noise": spec.noise, "seed": spec.demo_seed}
    return (
        not checkpoint_path(meta, spec.method, spec.obs_mode, spec.seed).exists()
        or not demo_path(spec.task, spec.samples, spec.noise, spec.demo_seed).exists()
    )


def run_seconds(
    spec: RunSpec,
    steps_per_s: float,
    pretrain_s: dict[str, float],
    sigma_fit_s: float = 0.0,
    total_steps: int = 300_000,
) -> float:
    """Estimated duration of one run on one core (module docstring, "A run lasts"). A run whose start sigma is fitted
    to another method's network (``RL_START_SIGMA == "spread"``: L2 follows VD's, as the method's ``spread_from``
    says) needs that method's checkpoint of its data set and seed too, and is costed as making it: it may start
    before, or beside, the run that would."""
    entry = method(spec.method)
    seconds = total_steps / steps_per_s
    if entry.pretrains:
        seconds += sigma_fit_s + (pretrain_s[spec.method] if needs_pretraining(spec) else 0.0)
        follows = entry.spread_from
        if (
            RL_START_SIGMA == "spread"
            and follows not in (None, spec.method)
            and needs_pretraining(replace(spec, method=follows))
        ):
            seconds += pretrain_s[follows]
    return seconds


def wall_time_table(
    steps_per_s: float,
    pretrain_s: dict[str, float],
    sigma_fit_s: float = 0.0,
    cores=(2, 8, 16, 32, 64),
    seeds=(0, 1, 2),
    total_steps: int = 300_000,
    obs_mode: str = "rgbd",
) -> str:
    """A Markdown table of estimated wall time (hours) by number of cores for the image Fig. 4 alone and
    for the whole image section (Figs. 4-7, one shared state folder). ``pretrain_s``: seconds of one
    pre-training per method that pre-trains."""
    groups = {"Fig. 4": ["fig4"], "Figs. 4-7": list(FIGURES)}
    runs = {group: distinct_runs(names, seeds, total_steps, obs_mode) for group, names in groups.items()}
    seconds = {
        group: [run_seconds(spec, steps_per_s, pretrain_s, sigma_fit_s, total_steps) for spec in specs]
        for group, specs in runs.items()
    }
    header = " | ".join(
        f"{group}: {len(specs)} runs ({sum(map(needs_pretraining, specs))} pre-train first)"
        for group, specs in runs.items()
    )
    lines = [f"| cores | {header} |", "|---|" + "---|" * len(groups)]
    for n in cores:
        hours = " | ".join(f"{makespan(seconds[group], n) / 3600:.1f} h" for group in groups)
        lines.append(f"| {n} | {hours} |")
    return "\n".join(lines)
