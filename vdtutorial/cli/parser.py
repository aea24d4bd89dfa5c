"""The parser of ``python -m vdtutorial``: every command, its options and their help.

Not taught in a chapter: the command line's plumbing (chapter 00 shows the commands, vdtutorial/cli/).
"""

from __future__ import annotations

import argparse

from vdtutorial.cli.arguments import (
    OneLineParser,
    add_exact_kernels,
    add_force,
    add_progress,
    epochs_help,
    fraction,
    help_when_shown,
    nonnegative_float,
    nonnegative_int,
    plan_help,
    plan_name,
    positive_int,
)
from vdtutorial.cli.commands import (
    GRID_ONLY,
    STATE_ONLY,
    cmd_ablations,
    cmd_bench,
    cmd_book,
    cmd_claims,
    cmd_demos,
    cmd_digits,
    cmd_dropout_rate,
    cmd_evaluate,
    cmd_experiment,
    cmd_expert,
    cmd_notebooks,
    cmd_pretrain,
    cmd_rederive,
    cmd_reproduce,
)
from vdtutorial.settings import QUICK_ENV, data_dir

#: What ``python -m vdtutorial --help`` says first.
DESCRIPTION = """The command line of vdtutorial: python -m vdtutorial COMMAND ... (COMMAND --help for its options).

Commands write what they make under runs/ unless --out says otherwise; they never replace a file in
data/ (the shipped artefacts the notebooks and figures rely on) without --force."""


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="python -m vdtutorial", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=OneLineParser)

    _add_pipeline_commands(sub)
    _add_measurement_commands(sub)
    _add_experiment_commands(sub)
    from vdtutorial.course import classroom

    classroom.add_parser(sub)
    return parser


def _add_pipeline_commands(sub) -> None:
    """The pipeline's steps one at a time: demonstrations, the expert, pre-training, evaluation."""
    p = sub.add_parser("demos", help="generate expert demonstrations (eqs. 5-8)")
    p.add_argument("--task", choices=("reach", "grasp"), default="reach", help="which task's expert (default reach)")
    p.add_argument(
        "--samples", type=positive_int, default=8000, help="state-action pairs in the data set (default 8000)"
    )
    p.add_argument(
        "--noise",
        type=nonnegative_float,
        default=None,
        help="Sigma: std of the action noise in radians (default: the shipped sets', 0.5 reach, 0.03 grasp)",
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seeds the cup positions and the noise (default 0)")
    p.add_argument("--out", default=None, help="output file (default: runs/demos/TASK_nN_sigmaS_seedK.npz)")
    add_force(p)
    add_progress(p)
    p.set_defaults(func=cmd_demos)

    p = sub.add_parser("expert", help="measure the IK expert's success rate")
    p.add_argument(
        "--task",
        nargs="+",
        choices=("reach", "grasp"),
        default=["reach", "grasp"],
        help="one or both tasks (default: both)",
    )
    p.add_argument(
        "--episodes", type=positive_int, default=200, help="noiseless expert trajectories per task (default 200)"
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="trajectory k uses cup seed SEED + k (default 0)")
    add_progress(p)
    p.set_defaults(func=cmd_expert)

    p = sub.add_parser("pretrain", help="behavioural cloning with sparse VD or L2 (eqs. 1-4)")
    add_exact_kernels(p)
    p.add_argument(
        "--reg",
        required=True,
        metavar="METHOD",
        help="a pre-training method of vdtutorial.methods: vd (sparse variational dropout) or l2",
    )
    p.add_argument("--demos", required=True, help="a demonstrations file (python -m vdtutorial demos ...)")
    p.add_argument(
        "--seed",
        type=nonnegative_int,
        default=0,
        help="seeds the initialisation, the held-out split and the batches (default 0)",
    )
    p.add_argument(
        "--obs",
        choices=("state", "rgbd"),
        default="state",
        help="policy input: joint angles + cup position, or the paper's RGBD image + joints (default state)",
    )
    p.add_argument("--epochs", type=positive_int, default=None, action=help_when_shown(epochs_help))
    p.add_argument(
        "--patience",
        type=positive_int,
        default=None,
        metavar="P",
        help="stop when the held-out MSE has not improved for P epochs (after VD's KL warm-up); "
        "--epochs is then a cap, VD's KL warm-up keeps its default length in epochs, and mu is the best "
        "epoch's (default: run all epochs)",
    )
    p.add_argument(
        "--sigma",
        default="0.3",
        help="sigma the checkpoint starts RL from: a number (fixed; default 0.3, the network's initial "
        "value, which the paper leaves untouched and the shipped checkpoints hold; the experiments "
        "fit their start, 'spread', on top when they load a checkpoint), 'demos' (maximum likelihood "
        "on the demonstrations, mu frozen) or 'spread' (fitted to the VD network's predictive spread; "
        "L2 follows the VD checkpoint of the same seed)",
    )
    p.add_argument(
        "--out", default=None, help="checkpoint file (default: runs/checkpoints/TASK_nN_sigmaS_REG_OBS_seedK.pt)"
    )
    p.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="where behavioural cloning runs (default cpu; cuda: a CUDA GPU). On a GPU the numbers differ "
        "from the CPU's by floating-point rounding, and VD's weight noise comes from other random "
        "draws; the checkpoint is written from the CPU either way",
    )
    add_force(p)
    add_progress(p)
    p.set_defaults(func=cmd_pretrain)

    p = sub.add_parser("evaluate", help="successful trajectories per 200-step episode: pre-trained VD, L2, expert")
    p.add_argument(
        "--demos",
        default=str(data_dir() / "demos" / "reach_n8000_sigma0.5_seed0.npz"),
        help="the demonstrations the policies were trained on (default: the shipped reach set)",
    )
    p.add_argument("--obs", choices=("state", "rgbd"), default="state", help="which policies to load (default state)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="pre-training seed of the checkpoints (default 0)")
    p.add_argument(
        "--checkpoints",
        default=None,
        help="folder holding the checkpoints (default: data/checkpoints; e.g. runs/checkpoints)",
    )
    p.add_argument("--episodes", type=positive_int, default=None, help="200-step episodes per controller (default 5)")
    p.set_defaults(func=cmd_evaluate)


def _add_measurement_commands(sub) -> None:
    """What measures this machine or a building block: the digits check and the benchmarks."""
    p = sub.add_parser("digits", help="validate sparse VD on scikit-learn's digits (dense vs VD MLP)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seeds the split and the training (default 0)")
    p.set_defaults(func=cmd_digits)

    p = sub.add_parser(
        "dropout-rate",
        help="the binary dropout rate matched to VD checkpoints of one data set: mean alpha/(1+alpha) of the kept "
        "weights, per checkpoint and averaged over them",
    )
    p.add_argument(
        "checkpoints",
        nargs="+",
        help="VD checkpoints (e.g. data/checkpoints/reach_n2000_sigma0.5_vd_state_seed0.pt and those pretrain "
        "--reg vd makes for other seeds), all of one data set",
    )
    p.set_defaults(func=cmd_dropout_rate)

    p = sub.add_parser("bench", help="benchmarks: env, policy, finetune, trpo")
    p.add_argument(
        "what",
        choices=("env", "policy", "finetune", "trpo"),
        help="env: steps/s; policy: network and pre-training cost; finetune: TRPO fine-tuning steps/s "
        "end to end; trpo: our TRPO against sb3-contrib's on Pendulum-v1 (needs the bench extra)",
    )
    p.add_argument(
        "--seeds", type=nonnegative_int, nargs="+", default=None, help="trpo only: seeds (default: 11 12 13)"
    )
    p.add_argument("--steps", type=positive_int, default=None, help="trpo only: env steps per run (default: 100000)")
    p.add_argument(
        "--profile",
        action="store_true",
        help="finetune only: then profile the rgbd whole-batch case and print its top operators",
    )
    p.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="finetune only: where TRPO's updates run (default cpu; cuda: a CUDA GPU); the rollouts stay on "
        "the CPU. The update columns are then wall seconds with the GPU, the CPU ones what this "
        "process spent, waiting for the GPU included",
    )
    add_exact_kernels(p)
    p.set_defaults(func=cmd_bench)


def _add_execution_options(p) -> None:
    """Where and how an experiment's runs execute: the backend, saved states, the device."""
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default=None,
        help="where the runs execute: local worker processes (default), or Ray, one task per run "
        "with one CPU (pip install -e '.[cluster]'); without --address Ray starts locally "
        "with --workers CPUs",
    )
    p.add_argument(
        "--address",
        default=None,
        help="join this Ray cluster (e.g. auto, or HEAD_IP:6379; implies --backend ray); the nodes "
        "need the same install and the same paths (shared storage)",
    )
    p.add_argument(
        "--state-dir",
        default=None,
        help="folder of the runs' saved states, which make the experiment resumable: rerun the same "
        "command to continue it (default: OUT/runs; on a cluster, a folder on shared storage)",
    )
    p.add_argument(
        "--restart", action="store_true", help="discard the saved states of this experiment's runs and start them again"
    )
    p.add_argument(
        "--checkpoint-every",
        type=positive_int,
        default=None,
        metavar="K",
        help="TRPO iterations between two saved states of a run (default 10)",
    )
    p.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="figures only: where the runs' TRPO updates run (default cpu; cuda: a CUDA GPU, shared by the "
        "workers). Rollouts and pre-training stay on the CPU. Results on a GPU differ from the CPU's "
        "by floating-point rounding, so the rows are not the shipped ones bit for bit",
    )


def _add_experiment_commands(sub) -> None:
    """The paper's experiments and what reads them, the main job, and the chapters written out."""
    p = sub.add_parser(
        "experiment",
        help="the paper's experiments: fig4, fig5, fig6, fig7, table1; beyond "
        "(learned noise with DART, and DAgger, beside the hand-set Sigma); free_choices (our "
        "values the paper does not give, each changed alone); pretrain_stop (image pre-training stopped on the "
        "held-out loss)",
    )
    p.add_argument(
        "name",
        choices=("fig4", "fig5", "fig6", "fig7", "table1", *STATE_ONLY, *GRID_ONLY),
        help="which figure or table",
    )
    p.add_argument(
        "--seeds", type=nonnegative_int, nargs="+", default=None, help="default: 0 1 2 (table1: 0; beyond: 0-4)"
    )
    p.add_argument(
        "--methods",
        nargs="+",
        default=None,
        metavar="METHOD",
        help="figures only: run only these of the figure's methods (vd, l2, none, expert; default: all; "
        "e.g. more seeds of vd and l2, merged later with rederive --add), or beside them a method "
        "registered in vdtutorial.methods that pre-trains",
    )
    p.add_argument(
        "--samples",
        type=positive_int,
        nargs="+",
        default=None,
        metavar="N",
        help="figures only: run only the data sets of these sizes (e.g. fig5 --samples 2000)",
    )
    p.add_argument(
        "--sigmas",
        type=nonnegative_float,
        nargs="+",
        default=None,
        metavar="SIGMA",
        help="figures only: run only the data sets of these expert noises (e.g. fig6 --sigmas 0.05 0.25)",
    )
    p.add_argument(
        "--demo-seed",
        type=nonnegative_int,
        default=0,
        metavar="K",
        help="figures only: pre-train on the demonstrations of seed K (default 0, the shipped ones; "
        "make them first with: python -m vdtutorial demos ... --seed K --out data/demos/...)",
    )
    p.add_argument(
        "--choices",
        nargs="+",
        default=None,
        metavar="ROW",
        help="free_choices only: the rows to run besides the default one (default: all of them)",
    )
    p.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help="RL env steps per run (default: the paper's 3e5; beyond and free_choices: 1e5)",
    )
    p.add_argument("--obs", choices=("state", "rgbd"), default="state", help="policy input (default state)")
    p.add_argument("--workers", type=positive_int, default=2, help="runs in parallel, one per core (default 2)")
    p.add_argument("--out", default=None, help="output folder (default: runs/NAME; data/results/NAME only when named)")
    p.add_argument(
        "--fvp-subsample",
        type=fraction,
        default=None,
        help="fraction of each TRPO batch for the Fisher-vector products (default 1, the whole batch; "
        "0.1 is the subsampled control)",
    )
    p.add_argument(
        "--kl-weighting",
        choices=("per-set", "fixed"),
        default="per-set",
        help="table1 only: the N dividing the KL term, each data set's own (per-set, eq. 3 as written; "
        "default) or the 8000-sample set's for all (fixed)",
    )
    _add_execution_options(p)
    add_exact_kernels(p)
    p.set_defaults(
        func=cmd_experiment,
        on_interrupt="the finished runs and the saved states of the others are "
        "kept: rerun the same command (without --restart) to continue",
    )

    p = sub.add_parser("notebooks", help="write the chapters and the data they load into a folder of yours")
    p.add_argument("dest", help="the folder to write (made if missing); the chapters then run from DEST/notebooks")
    p.add_argument("--force", action="store_true", help="overwrite files you have changed since they were written")
    p.add_argument(
        "--student",
        action="store_true",
        help="the student edition (made by nbgrader as classroom release makes it), the solutions "
        "apart in DEST/solutions",
    )
    p.set_defaults(func=cmd_notebooks)

    p = sub.add_parser("book", help="execute the chapters and write them as a static HTML book that reads offline")
    p.add_argument("out", help="the folder to write (made if missing): OUT/index.html and one page per chapter")
    p.add_argument(
        "--full",
        action="store_true",
        help="run the chapters with the paper's budgets (default: quick mode, a few minutes in all)",
    )
    p.add_argument(
        "--chapters",
        nargs="+",
        default=None,
        metavar="NN",
        help="only these chapters, by number (e.g. 00 04 07; default: all)",
    )
    p.set_defaults(func=cmd_book)

    p = sub.add_parser("claims", help="the paper's claims as effect sizes with 95%% intervals, from experiment folders")
    p.add_argument(
        "folders", nargs="+", help="experiment folders (e.g. data/results/fig4); their JSON records are updated"
    )
    p.set_defaults(func=cmd_claims)

    p = sub.add_parser(
        "rederive",
        help="re-write experiment folders' figures and JSON summaries from their rows "
        "(measures, claims, Holm verdicts, detectable differences), running nothing",
    )
    p.add_argument("folders", nargs="+", help="experiment folders (e.g. data/results/fig4)")
    p.add_argument(
        "--add",
        nargs="+",
        default=[],
        metavar="OTHER",
        help="first add the runs of these folders, the same experiment run with other seeds (e.g. "
        "python -m vdtutorial rederive data/results/fig4 --add runs/fig4_seeds5-9)",
    )
    p.add_argument(
        "--add-other-cpu",
        nargs="+",
        default=[],
        metavar="OTHER",
        help="the same, for runs made with other CPU kernels than the folder's (each seed a valid "
        "replicate, but the rows no longer one command's on one CPU; the record says so)",
    )
    p.add_argument("--plan", type=plan_name, default=None, metavar="PLAN", action=help_when_shown(plan_help))
    p.set_defaults(func=cmd_rederive)

    p = sub.add_parser(
        "ablations",
        help="the ablations' record (docs/plan-ablations-and-image-fig5.md, section 2) from the plan's two finished "
        "experiment folders: the eight claims as one Holm family, the plan's reading, each run's final level",
    )
    p.add_argument("runs_fig6", metavar="RUNS_FIG6", help="the Fig. 6 folder (e.g. runs/ablations_fig6_sigma0.25)")
    p.add_argument("runs_fig5", metavar="RUNS_FIG5", help="the Fig. 5 folder (e.g. runs/ablations_fig5_n2000)")
    p.add_argument(
        "--out",
        default=None,
        help="the record's folder (default: runs/ablations; the shipped one: data/results/ablations); it also keeps "
        "the two folders' records and rows under rows/, from which the same command makes the record again",
    )
    p.set_defaults(func=cmd_ablations)

    p = sub.add_parser("reproduce", help="the main job: the whole pipeline at small scale (a few minutes on 2 cores)")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"quick mode, as {QUICK_ENV}=1: the same steps at tiny budgets, about a minute "
        "(default: the small scale, a few minutes)",
    )
    p.add_argument("--workers", type=positive_int, default=2, help="runs in parallel, one per core (default 2)")
    p.add_argument(
        "--out",
        default=None,
        help="output folder (default: runs/reproduce_quick; in quick mode runs/quick/reproduce_quick)",
    )
    add_exact_kernels(p)
    p.set_defaults(func=cmd_reproduce)
