"""The paper's experiments (Section V): Figs. 4-7, Table I and the sigma study, as functions that write
their evidence: Figs. 4-6 and the sigma study in chapter 07, Table I in chapter 05, Fig. 7 in chapter 08.

Modules, one idea each: :mod:`~vdtutorial.experiments.pipeline` (demonstrations -> pre-trained policy ->
policy ready for RL), :mod:`~vdtutorial.experiments.checkpoints` (the pre-trained policies' files, beside it),
:mod:`~vdtutorial.experiments.initial_sigma` (the sigma RL starts from), :mod:`~vdtutorial.experiments.runs`
(one run: TRPO from that policy, the expert's reference), :mod:`~vdtutorial.experiments.jobs` (runs as jobs of the
grid runner, :mod:`vdtutorial.runner`), :mod:`~vdtutorial.experiments.measures` (what a point of a curve measures),
:mod:`~vdtutorial.experiments.curves` (smoothing, bands, "steps to reach"),
:mod:`~vdtutorial.experiments.effects` (claims as effect sizes), :mod:`~vdtutorial.experiments.plans` (a test
fixed before its runs), :mod:`~vdtutorial.experiments.plots`
(the figure), :mod:`~vdtutorial.experiments.results` (an experiment's files),
:mod:`~vdtutorial.experiments.figures` (Figs. 4-7), :mod:`~vdtutorial.experiments.estimate` (a grid's
cost), :mod:`~vdtutorial.experiments.sparsity_table` (Table I), :mod:`~vdtutorial.experiments.sigma_study`
(sigma at the start of RL), :mod:`~vdtutorial.experiments.reproduce` (the whole pipeline, small),
:mod:`~vdtutorial.experiments.evaluation` (a controller's successes), :mod:`~vdtutorial.experiments.digits`
(sparse VD on handwritten digits) and :mod:`~vdtutorial.experiments.pendulum` (TRPO against sb3-contrib).
Their public names are importable from here.

What a run, a point of a curve, a seed and a band are, and where the files go: ``docs/experiments.md``.

Taught in chapters 05, 07 and 08.
"""

from vdtutorial.experiments.curves import (
    CONFIDENCE,
    Curve,
    curves_from_rows,
    mean_band,
    moving_average,
    smooth_window,
    steps_to_reach,
    vd_reaches_l2_final,
)
from vdtutorial.experiments.effects import CLAIMS, claim_effects, claim_table
from vdtutorial.experiments.record_claims import write_claims
from vdtutorial.experiments.figures import fig4, fig5, fig6, fig7
from vdtutorial.experiments.jobs import RunSpec
from vdtutorial.experiments.measures import MEASURES, measures_of
from vdtutorial.experiments.plots import METRIC_LABELS, figure_title, plot_curves, plot_measures
from vdtutorial.experiments.reproduce import reproduce_quick
from vdtutorial.experiments.results import (
    ExperimentResult,
    derive,
    experiment_command,
    format_summary,
    load_result,
    merge_seeds,
    rederive,
    run_experiment,
)
from vdtutorial.experiments.pipeline import finetune_policy, load_demos, pretrained_policy, ready_for_rl
from vdtutorial.experiments.runs import (
    CHECKPOINT_EVERY,
    METRIC,
    NUM_ENVS,
    RL_METHODS,
    SUBSAMPLED_FISHER_CONFIG,
    default_expert_episodes,
    default_seeds,
    default_total_steps,
    default_trpo_config,
    expert_reference,
    finetune,
    finetune_steps,
)
from vdtutorial.methods import METHOD_LABELS, METHODS
from vdtutorial.experiments.sparsity_table import (
    KL_WEIGHTINGS,
    TABLE1,
    format_table1,
    seeds_with_trend,
    sparsity_trends,
    table1,
    table_means,
)
from vdtutorial.runner import ResumeError, read_rows, results_file, run_grid, run_jobs, stored_rows, write_csv
