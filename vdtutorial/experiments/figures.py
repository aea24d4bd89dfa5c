"""Figs. 4-7 as functions: the runs of each figure handed to :func:`run_experiment`. Taught in chapter 07."""

from __future__ import annotations

import math

from vdtutorial.demos import SHIPPED_NOISE
from vdtutorial.experiments.curves import vd_reaches_l2_final
from vdtutorial.experiments.jobs import RunSpec
from vdtutorial.experiments.results import ExperimentResult, experiment_command, run_experiment
from vdtutorial.experiments.runs import default_seeds, default_total_steps, default_trpo_config
from vdtutorial.methods import METHOD_LABELS, is_shipped, method


#: Each figure's runs: (title, methods, task, data sets (samples, Sigma) of the pre-trained methods, the
#: label of a pre-trained curve from (method, samples, Sigma)).
FIGURES = {
    "fig4": (
        "Fig. 4: reaching, different pre-training",
        ("vd", "l2", "none", "expert"),
        "reach",
        ((8000, 0.5),),
        lambda method, n, sigma: METHOD_LABELS[method],
    ),
    "fig5": (
        "Fig. 5: reaching, data set size",
        ("vd", "l2"),
        "reach",
        ((2000, 0.5), (4000, 0.5), (8000, 0.5)),
        lambda method, n, sigma: f"{METHOD_LABELS[method]}, {n} demos",
    ),
    "fig6": (
        "Fig. 6: reaching, expert noise",
        ("vd", "l2"),
        "reach",
        ((8000, 0.05), (8000, 0.25), (8000, 0.5)),
        lambda method, n, sigma: f"{METHOD_LABELS[method]}, Sigma={sigma:g}",
    ),
    "fig7": (
        "Fig. 7: grasping",
        ("vd", "l2", "none", "expert"),
        "grasp",
        ((8000, SHIPPED_NOISE["grasp"]),),
        lambda method, n, sigma: METHOD_LABELS[method],
    ),
}


def figure_methods(name: str, methods=None) -> tuple[str, ...]:
    """Figure ``name``'s methods in its own order, only those of ``methods`` when given, followed by any other
    method of ``methods`` that pre-trains (:mod:`vdtutorial.methods`: a method of your own, run on the figure's
    data sets beside the paper's). ValueError for a method not in the table, or one that does not pre-train and
    is not the figure's."""
    all_methods = FIGURES[name][1]
    if methods is None:
        return all_methods
    entries = [method(m) for m in dict.fromkeys(methods)]  # ValueError for a name not in the table
    foreign = [entry.name for entry in entries if entry.name not in all_methods and not entry.pretrains]
    if foreign:
        raise ValueError(
            f"{name} has no method {', '.join(foreign)}: its methods are {', '.join(all_methods)}, "
            "and any that pre-trains"
        )
    return tuple(m for m in all_methods if m in methods) + tuple(e.name for e in entries if e.name not in all_methods)


def figure_data_sets(name: str, samples=None, sigmas=None) -> tuple[tuple[int, float], ...]:
    """Figure ``name``'s data sets (samples, Sigma), only those with one of ``samples`` and one of ``sigmas`` when
    given (ValueError when none is left)."""
    datasets = tuple(
        (n, sigma)
        for n, sigma in FIGURES[name][3]
        if (samples is None or n in samples) and (sigmas is None or any(math.isclose(sigma, s) for s in sigmas))
    )
    if not datasets:
        known = ", ".join(f"{n} demonstrations at Sigma {sigma:g}" for n, sigma in FIGURES[name][3])
        raise ValueError(f"{name} has no such data set: its data sets are {known}")
    return datasets


def figure_specs(
    name: str,
    seeds=None,
    total_steps: int | None = None,
    obs_mode: str = "state",
    methods=None,
    demo_seed: int = 0,
    samples=None,
    sigmas=None,
) -> list[RunSpec]:
    """The runs of a figure: each pre-training method on each data set, the other methods once, every one
    for every seed (defaults: :func:`~vdtutorial.experiments.runs.default_seeds`,
    :func:`~vdtutorial.experiments.runs.default_total_steps`). ``methods`` keeps only those of the figure's
    methods (``"vd"``, ``"l2"``, ``"none"``, ``"expert"``): extra seeds of some curves, merged later with
    ``rederive --add``; a method of the table that pre-trains but is not the figure's joins on its data sets.
    ``samples`` and ``sigmas`` keep only those data sets (:func:`figure_data_sets`), and
    ``demo_seed`` draws them again: the demonstrations of seed ``demo_seed`` in place of the shipped seed 0, to
    ask whether an effect survives a new draw of the data."""
    _, _, task, _, label = FIGURES[name]
    methods = figure_methods(name, methods)
    datasets = figure_data_sets(name, samples, sigmas)
    seeds = tuple(default_seeds() if seeds is None else seeds)
    total_steps = default_total_steps() if total_steps is None else total_steps
    specs = []
    for name_of in methods:
        if method(name_of).pretrains:
            specs += [
                RunSpec(name_of, task, n, sigma, seed, obs_mode, total_steps, label(name_of, n, sigma), demo_seed)
                for n, sigma in datasets
                for seed in seeds
            ]
        else:
            specs += [
                RunSpec(name_of, task, None, None, seed, obs_mode, total_steps, METHOD_LABELS[name_of])
                for seed in seeds
            ]
    return specs


def _figure(
    name: str,
    seeds,
    total_steps,
    obs_mode,
    out,
    workers,
    methods=None,
    demo_seed: int = 0,
    samples=None,
    sigmas=None,
    **kwargs,
) -> ExperimentResult:
    """The runs of figure ``name`` (:func:`figure_specs`) handed to :func:`run_experiment`."""
    specs = figure_specs(name, seeds, total_steps, obs_mode, methods, demo_seed, samples, sigmas)
    registered = sorted({spec.method for spec in specs if not is_shipped(spec.method)})
    if registered and workers > 1:
        raise ValueError(
            f"{', '.join(registered)}: registered in this process only, which other workers do not "
            "share: run with one worker"
        )
    trpo_config = kwargs.get("trpo_config")
    fvp_subsample = None  # in the command only when it is not the default
    if trpo_config is not None and trpo_config.fvp_subsample != default_trpo_config().fvp_subsample:
        fvp_subsample = trpo_config.fvp_subsample
    command = experiment_command(
        name,
        seeds=tuple(dict.fromkeys(spec.seed for spec in specs)),
        steps=specs[0].total_steps,
        obs=obs_mode,
        workers=workers,
        out=out,
        fvp_subsample=fvp_subsample,
        methods=None if methods is None else tuple(dict.fromkeys(s.method for s in specs)),
        samples=None if samples is None else tuple(dict.fromkeys(s.samples for s in specs if s.samples is not None)),
        sigmas=None
        if sigmas is None
        else tuple(f"{s:g}" for s in dict.fromkeys(s.noise for s in specs if s.noise is not None)),
        demo_seed=demo_seed or None,
    )
    return run_experiment(name, specs, FIGURES[name][0], out, workers, command=command, **kwargs)


def fig4(
    seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2, **kwargs
) -> ExperimentResult:
    """Fig. 4: VD vs L2 vs no pre-training vs the IK expert on reaching (8000 demonstrations, Sigma = 0.5),
    plus the paper's headline number: the env steps at which VD's smoothed mean curve first reaches L2's
    final level (paper: ~1.25e5 of 3e5), in ``result.summary["vd_reaches_l2_final"]`` (None: never).
    ``kwargs`` go to :func:`run_experiment` (``demos_root``, ``checkpoints_root``, configs, ``window``, and
    where and how the runs execute: ``backend``, ``address``, ``state_dir``, ``restart``, ``progress``)."""
    return _figure("fig4", seeds, total_steps, obs_mode, out, workers, summarise=_headline, **kwargs)


def _headline(curves) -> dict:
    """Fig. 4's headline comparison, where the experiment ran both VD and L2 (``methods`` may leave one out)."""
    if not {method("vd").label, method("l2").label} <= set(curves):
        return {}
    return {"vd_reaches_l2_final": vd_reaches_l2_final(curves)}


def fig5(
    seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2, **kwargs
) -> ExperimentResult:
    """Fig. 5: VD and L2 pre-trained on 2000, 4000 and 8000 demonstrations (Sigma = 0.5), reaching."""
    return _figure("fig5", seeds, total_steps, obs_mode, out, workers, **kwargs)


def fig6(
    seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2, **kwargs
) -> ExperimentResult:
    """Fig. 6: VD and L2 pre-trained on 8000 demonstrations with Sigma = 0.05, 0.25 and 0.5, reaching."""
    return _figure("fig6", seeds, total_steps, obs_mode, out, workers, **kwargs)


def fig7(
    seeds=None, total_steps: int | None = None, obs_mode: str = "state", out=None, workers: int = 2, **kwargs
) -> ExperimentResult:
    """Fig. 7: grasping, VD vs L2 vs no pre-training vs the IK expert, in cumulative reward per trajectory
    (8000 demonstrations, Sigma = ``SHIPPED_NOISE["grasp"]``)."""
    return _figure("fig7", seeds, total_steps, obs_mode, out, workers, **kwargs)
