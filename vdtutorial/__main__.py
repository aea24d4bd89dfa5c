"""The command line of vdtutorial: python -m vdtutorial COMMAND ... (COMMAND --help for its options).

Commands write what they make under runs/ unless --out says otherwise; they never replace a file in
data/ (the shipped artefacts the notebooks and figures rely on) without --force.

Taught in chapter 00.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

from vdtutorial.runner.kernels import can_pin, kernel_settings, pin_vector_kernels, pinned
from vdtutorial.settings import data_dir, is_quick, runs_dir

#: Set this environment variable to see the full traceback of an expected error.
TRACEBACK_VARIABLE = "VDTUTORIAL_TRACEBACK"


class CommandError(Exception):
    """An error the user can fix: printed as one line, exit code 2."""


# -- argument types: bad values are refused at parse time ------------------------------------------------
def _number_type(convert, accept, expected: str):
    """An argparse type: ``convert(text)``, refused with "expected EXPECTED" unless ``accept(value)``."""
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = None
        if value is None or not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value
    parse.__name__ = expected  # argparse names the type in some messages
    return parse


positive_int = _number_type(int, lambda v: v >= 1, "a positive integer")
nonnegative_int = _number_type(int, lambda v: v >= 0, "an integer >= 0")
nonnegative_float = _number_type(float, lambda v: math.isfinite(v) and v >= 0, "a finite number >= 0")
fraction = _number_type(float, lambda v: 0 < v <= 1, "a number in (0, 1]")


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``error: ...``, exit code 2) instead of the usage
    block followed by the message: ``--help`` shows the usage."""

    def error(self, message):
        self.exit(2, f"error: {self.prog}: {message} (see {self.prog} --help)\n")


# -- where outputs go ------------------------------------------------------------------------------------
def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def output_path(out: str | None, default: Path, force: bool) -> Path:
    """``--out`` if given, else ``default`` (under runs/). Refuses to replace an existing file in data/
    unless ``force``: the notebooks and figures rely on the shipped files."""
    path = Path(out) if out else default
    if path.exists() and _inside(path, data_dir()) and not force:
        raise CommandError(f"{path} is a shipped file in data/; pass --force to replace it, or --out another path")
    return path


def _device(args):
    """``--device`` as a torch.device, refused in one line (exit code 2) when this machine has no such device."""
    from vdtutorial.policy import torch_device

    return torch_device(args.device, "--device")


def _progress(args) -> bool:
    """Progress bars: on in a terminal, off in logs and pipes, unless --progress / --no-progress says."""
    return sys.stderr.isatty() if args.progress is None else args.progress


# -- the commands ----------------------------------------------------------------------------------------
def _cmd_demos(args) -> None:
    from vdtutorial.demos import SHIPPED_NOISE, demo_path, generate_demos

    noise = SHIPPED_NOISE[args.task] if args.noise is None else args.noise
    out = output_path(args.out, demo_path(args.task, args.samples, noise, args.seed, root=runs_dir()), args.force)
    demos = generate_demos(args.task, args.samples, noise, args.seed, progress=_progress(args))
    demos.save(out)
    print(f"{len(demos)} samples from {demos.meta['episodes']} noisy expert episodes "
          f"(noisy success rate {demos.meta['noisy_success_rate']:.2f})")
    print(f"wrote {out}")


def _cmd_expert(args) -> None:
    from vdtutorial.experiments.evaluation import expert_success_rate

    for task in args.task:
        rate, mean_len = expert_success_rate(task, args.episodes, seed=args.seed, progress=_progress(args))
        print(f"expert {task}: success rate {rate:.3f} over {args.episodes} episodes "
              f"(mean episode length {mean_len:.2f} steps)")


def _cmd_pretrain(args) -> None:
    import torch

    from vdtutorial.demos import Demos
    from vdtutorial.pretrain import (checkpoint_path, default_config, load_checkpoint, pretrain, pretrain_command,
                                     save_checkpoint)
    from vdtutorial.vd import sparsity_report

    device = _device(args)  # before any work
    torch.set_num_threads(1)
    demos = Demos.load(args.demos)
    config = default_config(args.reg, args.obs)
    if args.epochs:
        config = dataclasses.replace(config, epochs=args.epochs)
    config = dataclasses.replace(config, initial_sigma=args.sigma, patience=args.patience)
    out = output_path(args.out, checkpoint_path(demos.meta, args.reg, args.obs, args.seed, root=runs_dir(),
                                                initial_sigma=config.initial_sigma, patience=config.patience), args.force)
    spread_net = None
    if args.reg == "l2" and config.initial_sigma == "spread":  # L2 has no noise model: follow the VD network's
        spread_net = load_checkpoint(checkpoint_path(demos.meta, "vd", args.obs, args.seed), variational=True).mu
    policy, history = pretrain(demos, config, seed=args.seed, progress=_progress(args), spread_net=spread_net,
                               device=device)
    command = (pretrain_command(args.reg, args.demos, args.seed, args.obs, config.initial_sigma)
               + (f" --epochs {args.epochs}" if args.epochs else "")
               + (f" --patience {args.patience}" if args.patience else "")
               + (f" --device {args.device}" if args.device != "cpu" else ""))
    save_checkpoint(policy, out, {"command": command})
    kept = history[-1]
    if args.patience:
        info = policy.pretrain_info
        kept = history[info["best_epoch"] - 1]
        print(f"stopped on the held-out MSE after {info['epochs_run']} of at most {config.epochs} epochs; "
              f"mu is epoch {info['best_epoch']}'s")
    print(f"held-out imitation MSE {kept['val_mse']:.4f}")
    if args.reg == "vd":
        print(sparsity_report(policy.mu))
    print(f"wrote {out}")


def _cmd_evaluate(args) -> None:
    """The covariate-shift check before any RL (Section III-A): pre-trained policies vs the expert."""
    import gymnasium as gym
    import numpy as np

    from vdtutorial.demos import Demos
    from vdtutorial.envs import ENV_IDS
    from vdtutorial.experiments.evaluation import ExpertController, PolicyController, successes_per_episode
    from vdtutorial.pretrain import checkpoint_path, load_checkpoint
    from vdtutorial.settings import budget

    demos = Demos.load(args.demos)
    task = demos.meta["task"]
    folder = Path(args.checkpoints) if args.checkpoints else data_dir() / "checkpoints"
    controllers = {reg: PolicyController(load_checkpoint(folder / checkpoint_path(demos.meta, reg, args.obs, args.seed).name))
                   for reg in ("vd", "l2")}
    env = gym.make(ENV_IDS[task], obs_mode=args.obs)
    episodes = args.episodes or budget(5, 2)
    controllers["expert"] = ExpertController(env)
    for name, controller in controllers.items():
        runs = [successes_per_episode(env, controller, seed=100 + k) for k in range(episodes)]
        wins = np.array([r["successes"] for r in runs])
        reward = np.array([r["reward"] for r in runs])
        print(f"{name:7s} successes per 200-step episode {wins.mean():5.1f} +- {wins.std():4.1f}   "
              f"reward per episode {reward.mean():8.1f}   ({episodes} episodes, mean action)")
    env.close()


def _cmd_digits(args) -> None:
    from vdtutorial.vd import digits_validation

    result = digits_validation(seed=args.seed)
    print(f"dense MLP accuracy {result.dense_accuracy:.4f}; sparse VD MLP accuracy {result.vd_accuracy:.4f} "
          f"with {result.fraction_pruned:.1%} of weights pruned ({result.seconds:.1f} s)")
    print(result.report)


def _cmd_bench(args) -> None:
    from vdtutorial import bench

    if args.what != "finetune" and (args.profile or args.device != "cpu"):
        raise CommandError(f"{'--profile' if args.profile else '--device'} is an option of bench finetune only")
    which = "pinned, --exact-kernels" if pinned() else "this CPU's own"
    print(f"CPU kernels: {kernel_settings()['torch_cpu_capability']} ({which})")
    if args.what == "trpo":
        bench.bench_trpo_pendulum(seeds=args.seeds, total_steps=args.steps)
    elif args.what == "finetune":
        bench.bench_finetune(profile=args.profile, device=_device(args))
    else:
        {"env": bench.bench_env, "policy": bench.bench_policy}[args.what]()


def _cmd_reproduce(args) -> None:
    """The package's main job: the whole pipeline at small scale (see experiments.reproduce_quick)."""
    from vdtutorial.experiments import reproduce_quick

    _print_summary(reproduce_quick(out=args.out, workers=args.workers))


def _print_summary(result) -> None:
    """Final level of every curve, the fig4-style "VD reaches L2" line if any, and where files went."""
    from vdtutorial.experiments import format_summary

    print(format_summary(result))


#: Experiments without TRPO runs, and why the figures' resume options do not apply to them.
PRE_RL_ONLY = {"table1": "pre-trains only (no TRPO runs to resume)"}


#: The experiments beyond the figures, which run in state mode with the paper's TRPO settings on the CPU.
STATE_ONLY = ("beyond", "free_choices")
#: Experiments of our own settings that take only the grid's options (seeds, workers, out, backend, restart).
GRID_ONLY = {"pretrain_stop": "image pre-training stopped on the held-out loss against the fixed 40 epochs"}


def _state_only(args, backend: str) -> None:
    """The beyond experiment (chapter 09) or our free choices (chapter 07): the figures' options but the
    observation, the TRPO configuration and the device, which are fixed."""
    from vdtutorial.experiments import ResumeError

    name = args.name
    if args.obs != "state":
        raise CommandError(f"{name} runs in state mode only (--obs state)")
    if args.fvp_subsample is not None:
        raise CommandError(f"{name} fine-tunes with the paper's TRPO settings: --fvp-subsample is an option of the figures")
    if args.device != "cpu":
        raise CommandError(f"{name} runs on the CPU: --device is an option of the figures")
    options = dict(seeds=args.seeds, steps=args.steps, out=args.out, workers=args.workers, backend=backend,
                   address=args.address, restart=args.restart, state_dir=args.state_dir)
    if args.checkpoint_every is not None:
        options["checkpoint_every"] = args.checkpoint_every
    try:
        if name == "beyond":
            from vdtutorial.experiments.beyond import beyond, format_summary

            print(format_summary(beyond(**options)))
        else:
            from vdtutorial.experiments.free_choices import CHOICE_NAMES, format_table, free_choices

            unknown = sorted(set(args.choices or ()) - set(CHOICE_NAMES))
            if unknown:
                raise CommandError(f"--choices: unknown {', '.join(unknown)}; the rows are {', '.join(CHOICE_NAMES)}")
            print(format_table(free_choices(names=tuple(args.choices or CHOICE_NAMES), **options)))
    except ResumeError as exc:
        raise CommandError(str(exc)) from exc


def _grid_only(args, backend: str) -> None:
    """An experiment of :data:`GRID_ONLY`: it fixes its observation, budget and TRPO settings itself."""
    from vdtutorial.experiments import ResumeError
    from vdtutorial.experiments.pretrain_stop import format_comparison, pretrain_stop

    fixed = [flag for flag, value in (("--steps", args.steps), ("--obs", None if args.obs == "state" else args.obs),
                                      ("--fvp-subsample", args.fvp_subsample), ("--checkpoint-every", args.checkpoint_every),
                                      ("--device", None if args.device == "cpu" else args.device)) if value is not None]
    if fixed:
        raise CommandError(f"{args.name} sets {', '.join(fixed)} itself (it compares {GRID_ONLY[args.name]})")
    try:
        record = pretrain_stop(seeds=args.seeds, out=args.out, workers=args.workers, backend=backend,
                               address=args.address, restart=args.restart, state_dir=args.state_dir)
    except ResumeError as exc:
        raise CommandError(str(exc)) from exc
    print(format_comparison(record))


def _cmd_experiment(args) -> None:
    import warnings

    from vdtutorial import experiments

    if args.address is not None and args.backend == "local":
        raise CommandError("--address names a Ray cluster: use it with --backend ray")
    backend = args.backend or ("ray" if args.address is not None else "local")
    resumable = {"checkpoint_every": args.checkpoint_every} if args.checkpoint_every is not None else {}
    if args.kl_weighting != "per-set" and args.name != "table1":
        raise CommandError("--kl-weighting is an option of table1 (the figures use the pre-training default)")
    if args.choices is not None and args.name != "free_choices":
        raise CommandError("--choices is an option of free_choices")
    if args.methods is not None:
        from vdtutorial.experiments.figures import FIGURES, figure_methods

        if args.name not in FIGURES:
            raise CommandError("--methods is an option of the figures")
        try:
            figure_methods(args.name, args.methods)
        except ValueError as exc:
            raise CommandError(str(exc)) from exc
    if args.name in PRE_RL_ONLY:
        ignored = [flag for flag, value in (("--steps", args.steps), ("--fvp-subsample", args.fvp_subsample),
                                            ("--state-dir", args.state_dir), ("--checkpoint-every", args.checkpoint_every),
                                            ("--restart", args.restart or None),
                                            ("--device", None if args.device == "cpu" else args.device))
                   if value is not None]
        if ignored:
            raise CommandError(f"{args.name} {PRE_RL_ONLY[args.name]}: {', '.join(ignored)} "
                               f"{'are options' if len(ignored) > 1 else 'is an option'} of the figures")
        experiments.table1(obs_mode=args.obs, seeds=args.seeds or (0,), kl_weighting=args.kl_weighting,
                           out=args.out, workers=args.workers, backend=backend, address=args.address)
        return
    if args.name in STATE_ONLY:
        _state_only(args, backend)
        return
    if args.name in GRID_ONLY:
        _grid_only(args, backend)
        return
    _device(args)  # refused before any run starts
    trpo_config = None
    if args.fvp_subsample is not None:
        trpo_config = dataclasses.replace(experiments.default_trpo_config(), fvp_subsample=args.fvp_subsample)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            result = getattr(experiments, args.name)(
                seeds=args.seeds, total_steps=args.steps, obs_mode=args.obs, out=args.out, workers=args.workers,
                trpo_config=trpo_config, backend=backend, address=args.address, state_dir=args.state_dir,
                restart=args.restart, device=args.device, methods=args.methods, **resumable)
        except experiments.ResumeError as exc:
            raise CommandError(str(exc)) from exc
    _print_summary(result)


def _cmd_notebooks(args) -> None:
    """The chapters and the data they load, written into a folder of the learner's (see vdtutorial.course.chapters)."""
    from vdtutorial.course.chapters import EditedFilesError, NoNbgraderError, write_notebooks

    try:
        book = write_notebooks(args.dest, force=args.force, student=args.student)
    except (EditedFilesError, NoNbgraderError) as exc:
        raise CommandError(str(exc)) from exc
    edition = "the student edition of " if args.student else ""
    print(f"wrote {edition}{book.chapters} chapters and {book.data_files} data files into {book.dest}; start with "
          f"jupyter lab {book.dest / 'notebooks' / '00_start_here.ipynb'}")
    if book.solutions:
        print(f"the {book.solutions} chapters with every exercise solved are in {book.dest / 'solutions'}: "
              "open them when you have tried")


def _cmd_book(args) -> None:
    """The chapters executed and exported as a static HTML book that reads offline (see vdtutorial.course.html_book)."""
    from vdtutorial.course.html_book import build_book

    start = time.perf_counter()
    book = build_book(args.out, numbers=args.chapters, quick=not args.full)
    print(f"wrote {len(book.chapters)} chapters in {time.perf_counter() - start:.0f} s; open {book.index}")


def _cmd_claims(args) -> None:
    """The paper's claims as effect sizes with 95% intervals, from an experiment's rows (see experiments.effects)."""
    from vdtutorial.experiments import write_claims

    for folder in args.folders:
        if not Path(folder).is_dir() or not list(Path(folder).glob("*.json")):
            raise CommandError(f"{folder} is not an experiment folder (python -m vdtutorial experiment ... writes one)")
        print(f"{folder}:\n{write_claims(folder)}\n")


def _cmd_rederive(args) -> None:
    """An experiment's figure and JSON summary re-written from its rows (see experiments.results.rederive)."""
    from vdtutorial.experiments import format_summary, merge_seeds, rederive

    for folder in args.folders + args.add + args.add_other_cpu:
        if not Path(folder).is_dir() or not list(Path(folder).glob("*.json")):
            raise CommandError(f"{folder} is not an experiment folder (python -m vdtutorial experiment ... writes one)")
    if (args.add or args.add_other_cpu) and len(args.folders) != 1:
        raise CommandError("--add merges into one experiment folder: name one")
    for other in args.add:
        merge_seeds(args.folders[0], other)
    for other in args.add_other_cpu:
        merge_seeds(args.folders[0], other, other_cpu=True)
    for folder in args.folders:
        print(format_summary(rederive(folder)))


# -- the parser ------------------------------------------------------------------------------------------
def _epochs_help() -> str:
    from vdtutorial.pretrain import default_config

    return (f"passes over the training split (default: {default_config('vd', 'state').epochs} with --obs state, "
            f"{default_config('vd', 'rgbd').epochs} with --obs rgbd)")


def _add_progress(p) -> None:
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bars on standard error (default: only in a terminal)")


def _add_force(p) -> None:
    p.add_argument("--force", action="store_true", help="allow replacing an existing file in data/")


def _add_exact_kernels(p) -> None:
    p.add_argument("--exact-kernels", action="store_true",
                   help="pin torch's and numpy's CPU kernels to AVX2 (the command starts again with them pinned), "
                        "so that shipped results regenerate bit for bit; default: this CPU's own, faster kernels")


def _exact_kernels(args, argv) -> None:
    """``--exact-kernels``: start this command again with the AVX2 pins of :mod:`vdtutorial.runner.kernels` in its
    environment. numpy is already loaded when the arguments are parsed, and its OpenBLAS chose its kernels then, so
    setting the variables here would reach torch but not numpy: only a new process gets both."""
    if not getattr(args, "exact_kernels", False) or pinned():
        return
    if not can_pin():
        print("note: --exact-kernels: this CPU has no AVX2 kernels to pin, so it runs its own", file=sys.stderr)
        return
    if argv is not None:
        raise CommandError("--exact-kernels restarts the command: run it as a program (python -m vdtutorial ...), "
                           "or set the variables of vdtutorial.runner.kernels.PINNED before Python starts")
    env = dict(os.environ)
    pin_vector_kernels(env)
    sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, "-m", "vdtutorial", *sys.argv[1:]], env)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m vdtutorial", description=__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
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
    p.add_argument("--samples", type=positive_int, default=8000, help="state-action pairs in the data set (default 8000)")
    p.add_argument("--noise", type=nonnegative_float, default=None,
                   help="Sigma: std of the action noise in radians (default: the shipped sets', 0.5 reach, 0.03 grasp)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seeds the cup positions and the noise (default 0)")
    p.add_argument("--out", default=None, help="output file (default: runs/demos/TASK_nN_sigmaS_seedK.npz)")
    _add_force(p)
    _add_progress(p)
    p.set_defaults(func=_cmd_demos)

    p = sub.add_parser("expert", help="measure the IK expert's success rate")
    p.add_argument("--task", nargs="+", choices=("reach", "grasp"), default=["reach", "grasp"],
                   help="one or both tasks (default: both)")
    p.add_argument("--episodes", type=positive_int, default=200, help="noiseless expert trajectories per task (default 200)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="trajectory k uses cup seed SEED + k (default 0)")
    _add_progress(p)
    p.set_defaults(func=_cmd_expert)

    p = sub.add_parser("pretrain", help="behavioural cloning with sparse VD or L2 (eqs. 1-4)")
    _add_exact_kernels(p)
    p.add_argument("--reg", choices=("vd", "l2"), required=True, help="regulariser: sparse variational dropout or L2")
    p.add_argument("--demos", required=True, help="a demonstrations file (python -m vdtutorial demos ...)")
    p.add_argument("--seed", type=nonnegative_int, default=0,
                   help="seeds the initialisation, the held-out split and the batches (default 0)")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state",
                   help="policy input: joint angles + cup position, or the paper's RGBD image + joints (default state)")
    p.add_argument("--epochs", type=positive_int, default=None, help=_epochs_help())
    p.add_argument("--patience", type=positive_int, default=None, metavar="P",
                   help="stop when the held-out MSE has not improved for P epochs (after VD's KL warm-up); "
                        "--epochs is then a cap and mu is the best epoch's (default: run all epochs)")
    p.add_argument("--sigma", default="0.3",
                   help="sigma the checkpoint starts RL from: a number (fixed; default 0.3, the network's initial "
                        "value, which the paper leaves untouched and the shipped checkpoints hold; the experiments "
                        "fit their start, 'spread', on top when they load a checkpoint), 'demos' (maximum likelihood "
                        "on the demonstrations, mu frozen) or 'spread' (fitted to the VD network's predictive spread; "
                        "L2 follows the VD checkpoint of the same seed)")
    p.add_argument("--out", default=None, help="checkpoint file (default: runs/checkpoints/TASK_nN_sigmaS_REG_OBS_seedK.pt)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="where behavioural cloning runs (default cpu; cuda: a CUDA GPU). On a GPU the numbers differ "
                        "from the CPU's by floating-point rounding, and VD's weight noise comes from other random "
                        "draws; the checkpoint is written from the CPU either way")
    _add_force(p)
    _add_progress(p)
    p.set_defaults(func=_cmd_pretrain)

    p = sub.add_parser("evaluate", help="successful trajectories per 200-step episode: pre-trained VD, L2, expert")
    p.add_argument("--demos", default=str(data_dir() / "demos" / "reach_n8000_sigma0.5_seed0.npz"),
                   help="the demonstrations the policies were trained on (default: the shipped reach set)")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state", help="which policies to load (default state)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="pre-training seed of the checkpoints (default 0)")
    p.add_argument("--checkpoints", default=None,
                   help="folder holding the checkpoints (default: data/checkpoints; e.g. runs/checkpoints)")
    p.add_argument("--episodes", type=positive_int, default=None, help="200-step episodes per controller (default 5)")
    p.set_defaults(func=_cmd_evaluate)


def _add_measurement_commands(sub) -> None:
    """What measures this machine or a building block: the digits check and the benchmarks."""
    p = sub.add_parser("digits", help="validate sparse VD on scikit-learn's digits (dense vs VD MLP)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seeds the split and the training (default 0)")
    p.set_defaults(func=_cmd_digits)

    p = sub.add_parser("bench", help="benchmarks: env, policy, finetune, trpo")
    p.add_argument("what", choices=("env", "policy", "finetune", "trpo"),
                   help="env: steps/s; policy: network and pre-training cost; finetune: TRPO fine-tuning steps/s "
                        "end to end; trpo: our TRPO against sb3-contrib's on Pendulum-v1 (needs the bench extra)")
    p.add_argument("--seeds", type=nonnegative_int, nargs="+", default=None, help="trpo only: seeds (default: 11 12 13)")
    p.add_argument("--steps", type=positive_int, default=None, help="trpo only: env steps per run (default: 100000)")
    p.add_argument("--profile", action="store_true",
                   help="finetune only: then profile the rgbd whole-batch case and print its top operators")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="finetune only: where TRPO's updates run (default cpu; cuda: a CUDA GPU); the rollouts stay on "
                        "the CPU. The update columns are then wall seconds with the GPU, the CPU ones what this "
                        "process spent, waiting for the GPU included")
    _add_exact_kernels(p)
    p.set_defaults(func=_cmd_bench)


def _add_execution_options(p) -> None:
    """Where and how an experiment's runs execute: the backend, saved states, the device."""
    p.add_argument("--backend", choices=("local", "ray"), default=None,
                   help="where the runs execute: local worker processes (default), or Ray, one task per run "
                        "with one CPU (pip install -e '.[cluster]'); without --address Ray starts locally "
                        "with --workers CPUs")
    p.add_argument("--address", default=None,
                   help="join this Ray cluster (e.g. auto, or HEAD_IP:6379; implies --backend ray); the nodes "
                        "need the same install and the same paths (shared storage)")
    p.add_argument("--state-dir", default=None,
                   help="folder of the runs' saved states, which make the experiment resumable: rerun the same "
                        "command to continue it (default: OUT/runs; on a cluster, a folder on shared storage)")
    p.add_argument("--restart", action="store_true",
                   help="discard the saved states of this experiment's runs and start them again")
    p.add_argument("--checkpoint-every", type=positive_int, default=None, metavar="K",
                   help="TRPO iterations between two saved states of a run (default 10)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="figures only: where the runs' TRPO updates run (default cpu; cuda: a CUDA GPU, shared by the "
                        "workers). Rollouts and pre-training stay on the CPU. Results on a GPU differ from the CPU's "
                        "by floating-point rounding, so the rows are not the shipped ones bit for bit")


def _add_experiment_commands(sub) -> None:
    """The paper's experiments and what reads them, the main job, and the chapters written out."""
    p = sub.add_parser("experiment", help="the paper's experiments: fig4, fig5, fig6, fig7, table1; beyond "
                       "(learned noise with DART, and DAgger, beside the hand-set Sigma); free_choices (our "
                       "values the paper does not give, each changed alone); pretrain_stop (image pre-training stopped on the "
                       "held-out loss)")
    p.add_argument("name", choices=("fig4", "fig5", "fig6", "fig7", "table1", *STATE_ONLY, *GRID_ONLY),
                   help="which figure or table")
    p.add_argument("--seeds", type=nonnegative_int, nargs="+", default=None, help="default: 0 1 2 (table1: 0; beyond: 0-4)")
    p.add_argument("--methods", nargs="+", choices=("vd", "l2", "none", "expert"), default=None,
                   help="figures only: run only these of the figure's methods (default: all; e.g. more seeds of "
                        "vd and l2, merged later with rederive --add)")
    p.add_argument("--choices", nargs="+", default=None, metavar="ROW",
                   help="free_choices only: the rows to run besides the default one (default: all of them)")
    p.add_argument("--steps", type=positive_int, default=None, help="RL env steps per run (default: the paper's 3e5; beyond and free_choices: 1e5)")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state", help="policy input (default state)")
    p.add_argument("--workers", type=positive_int, default=2, help="runs in parallel, one per core (default 2)")
    p.add_argument("--out", default=None, help="output folder (default: runs/NAME; data/results/NAME only when named)")
    p.add_argument("--fvp-subsample", type=fraction, default=None,
                   help="fraction of each TRPO batch for the Fisher-vector products (default 1, the whole batch; "
                        "0.1 is the subsampled control)")
    p.add_argument("--kl-weighting", choices=("per-set", "fixed"), default="per-set",
                   help="table1 only: the N dividing the KL term, each data set's own (per-set, eq. 3 as written; "
                        "default) or the 8000-sample set's for all (fixed)")
    _add_execution_options(p)
    _add_exact_kernels(p)
    p.set_defaults(func=_cmd_experiment, on_interrupt="the finished runs and the saved states of the others are "
                   "kept: rerun the same command (without --restart) to continue")

    p = sub.add_parser("notebooks", help="write the chapters and the data they load into a folder of yours")
    p.add_argument("dest", help="the folder to write (made if missing); the chapters then run from DEST/notebooks")
    p.add_argument("--force", action="store_true", help="overwrite files you have changed since they were written")
    p.add_argument("--student", action="store_true",
                   help="the student edition (made by nbgrader as classroom release makes it), the solutions "
                        "apart in DEST/solutions")
    p.set_defaults(func=_cmd_notebooks)

    p = sub.add_parser("book", help="execute the chapters and write them as a static HTML book that reads offline")
    p.add_argument("out", help="the folder to write (made if missing): OUT/index.html and one page per chapter")
    p.add_argument("--full", action="store_true",
                   help="run the chapters with the paper's budgets (default: quick mode, a few minutes in all)")
    p.add_argument("--chapters", nargs="+", default=None, metavar="NN",
                   help="only these chapters, by number (e.g. 00 04 07; default: all)")
    p.set_defaults(func=_cmd_book)

    p = sub.add_parser("claims", help="the paper's claims as effect sizes with 95%% intervals, from experiment folders")
    p.add_argument("folders", nargs="+", help="experiment folders (e.g. data/results/fig4); their JSON records are updated")
    p.set_defaults(func=_cmd_claims)

    p = sub.add_parser("rederive", help="re-write experiment folders' figures and JSON summaries from their rows "
                                        "(measures, claims, Holm verdicts, seeds needed), running nothing")
    p.add_argument("folders", nargs="+", help="experiment folders (e.g. data/results/fig4)")
    p.add_argument("--add", nargs="+", default=[], metavar="OTHER",
                   help="first add the runs of these folders, the same experiment run with other seeds (e.g. "
                        "python -m vdtutorial rederive data/results/fig4 --add runs/fig4_seeds5-9)")
    p.add_argument("--add-other-cpu", nargs="+", default=[], metavar="OTHER",
                   help="the same, for runs made with other CPU kernels than the folder's (each seed a valid "
                        "replicate, but the rows no longer one command's on one CPU; the record says so)")
    p.set_defaults(func=_cmd_rederive)

    p = sub.add_parser("reproduce", help="the main job: the whole pipeline at small scale (a few minutes on 2 cores)")
    p.add_argument("--quick", action="store_true", help="accepted for clarity; reproduce always runs small")
    p.add_argument("--workers", type=positive_int, default=2, help="runs in parallel, one per core (default 2)")
    p.add_argument("--out", default=None, help="output folder (default: runs/reproduce_quick)")
    _add_exact_kernels(p)
    p.set_defaults(func=_cmd_reproduce)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        _exact_kernels(args, argv)  # first: it may start the command again
        if is_quick():
            print("[quick mode: small budgets]", file=sys.stderr)
        args.func(args)
    except KeyboardInterrupt:  # Ctrl-C: one line saying what survives, and the shell's code for SIGINT
        hint = getattr(args, "on_interrupt", None)
        print(f"interrupted{': ' + hint if hint else ''}", file=sys.stderr)
        return 130
    except (CommandError, ValueError, OSError, ImportError) as exc:  # expected: bad path, corrupt file, bad value, Ray not installed
        if os.environ.get(TRACEBACK_VARIABLE):
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
