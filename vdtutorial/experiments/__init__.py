"""The paper's experiments (Section V): Figs. 4-7 and Table I, as functions that write their evidence.

Modules, one idea each: :mod:`~vdtutorial.experiments.runs` (one run: pre-trained policy -> TRPO, the
expert's reference), :mod:`~vdtutorial.experiments.resume` (a run's saved state), :mod:`~vdtutorial.experiments.run_lock`
(one process at a time per run), :mod:`~vdtutorial.experiments.grid` (a restartable grid of runs), :mod:`~vdtutorial.experiments.backends` (local processes or Ray),
:mod:`~vdtutorial.experiments.progress` (the grid's progress lines),
:mod:`~vdtutorial.experiments.measures` (what a point of a curve measures),
:mod:`~vdtutorial.experiments.curves` (smoothing, bands, "steps to reach"),
:mod:`~vdtutorial.experiments.plots` (the figure), :mod:`~vdtutorial.experiments.rows` (CSV files),
:mod:`~vdtutorial.experiments.results` (an experiment's files), :mod:`~vdtutorial.experiments.figures`
(Figs. 4-7), :mod:`~vdtutorial.experiments.sparsity_table` (Table I) and
:mod:`~vdtutorial.experiments.reproduce` (the whole pipeline, small). Their public names are importable
from here.

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
    ``smooth_window()`` = 25 iterations = 5000 env steps, 1.7% of the paper's 3e5; the first points average
    the iterations available so far). Trailing, so that a smoothed value at step x uses only what the run
    had seen by then, which keeps "the step at which VD first reaches L2's final level" honest. The band
    is a 95% Student-t confidence interval of the mean over seeds at each point:
    mean +- t_{0.975, n-1} * sd / sqrt(n) (no band for a single seed). With 3 seeds t = 4.30, so bands are
    wide: they show how much the seeds disagree, not a significance test.

Parallelism, interruptions and reproducibility
    Runs are independent, so a grid sends them to a backend: local worker processes (``workers=2`` for
    2 cores) or Ray, on this machine or a cluster (:mod:`~vdtutorial.experiments.backends`). Every run
    uses one torch thread and is a pure function of its settings, so the results do not depend on the
    backend or the number of workers. Each run saves its state every ``CHECKPOINT_EVERY`` iterations;
    running the same experiment again continues where it stopped, with the rows of an uninterrupted
    run (:mod:`~vdtutorial.experiments.grid`, :mod:`~vdtutorial.experiments.resume`).

Where files go
    Results: ``runs/NAME/`` beside ``data/`` (``runs/quick/NAME/`` in quick mode, see ``RUNS_DIR``);
    the shipped reference results in ``data/results/NAME/`` are only replaced when ``out`` names them.
    Pre-trained checkpoints: the shipped ones in ``data/checkpoints/`` are used when they match the
    requested data set and configuration; otherwise they are made in the results folder. Each results
    folder holds ``runs/RUN.pt`` and ``runs/RUN.csv`` (each run's saved state and rows; another folder
    with ``state_dir``), ``NAME.csv.gz`` (all runs, one row per iteration, labelled by method, data set and
    seed), ``NAME.png`` (the figure) and ``NAME.json`` (the exact command, every configuration, the
    summary).
"""

from vdtutorial.experiments.curves import (CONFIDENCE, Curve, curves_from_rows, mean_band, moving_average,
                                           smooth_window, steps_to_reach, vd_reaches_l2_final)
from vdtutorial.experiments.effects import CLAIMS, claim_effects, claim_table, write_claims
from vdtutorial.experiments.figures import fig4, fig5, fig6, fig7
from vdtutorial.experiments.backends import run_jobs
from vdtutorial.experiments.grid import RunSpec, run_grid
from vdtutorial.experiments.plots import METRIC_LABELS, figure_title, plot_curves, plot_measures
from vdtutorial.experiments.reproduce import reproduce_quick
from vdtutorial.experiments.resume import ResumeError
from vdtutorial.experiments.measures import MEASURES, measures_of
from vdtutorial.experiments.results import (ExperimentResult, derive, experiment_command, format_summary, load_result,
                                           merge_seeds, rederive, run_experiment)
from vdtutorial.experiments.rows import read_rows, results_file, write_csv
from vdtutorial.experiments.runs import (CHECKPOINT_EVERY, METHOD_LABELS, METHODS, METRIC, NUM_ENVS, RL_METHODS,
                                         RUNS_DIR, SUBSAMPLED_FISHER_CONFIG, default_expert_episodes, default_seeds,
                                         default_total_steps, default_trpo_config, expert_reference, finetune,
                                         finetune_steps, load_demos, pretrained_policy)
from vdtutorial.experiments.sparsity_table import (KL_WEIGHTINGS, TABLE1, format_table1, seeds_with_trend,
                                                   sparsity_trends, table1, table_means)
