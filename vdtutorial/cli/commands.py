"""What each command of ``python -m vdtutorial`` does once its arguments are parsed: one ``cmd_NAME(args)`` per
command. Each imports what it needs when it runs, so ``--help`` and a usage error stay fast.

Not taught in a chapter: the command line's plumbing (chapter 00 shows the commands, vdtutorial/cli/).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

from vdtutorial.cli.arguments import CommandError, device_of, output_path, progress_of
from vdtutorial.settings import data_dir


def demos_output(args) -> Path:
    """The file a ``demos`` command writes, before ``--force`` is checked: ``--out``, or the conventional name under
    ``runs/demos``. (The provenance test reads every recorded command's output with this.)"""
    from vdtutorial.demos import SHIPPED_NOISE, demo_path
    from vdtutorial.experiments.paths import runs_dir

    noise = SHIPPED_NOISE[args.task] if args.noise is None else args.noise
    return Path(args.out) if args.out else demo_path(args.task, args.samples, noise, args.seed, root=runs_dir())


def pretrain_output(args, demos_meta: dict) -> Path:
    """The file a ``pretrain`` command writes from a data set with meta ``demos_meta``: ``--out``, or the
    conventional name under ``runs/checkpoints``, which names a non-default start sigma and early stop."""
    from vdtutorial.experiments.checkpoints import checkpoint_path
    from vdtutorial.experiments.paths import runs_dir

    return (
        Path(args.out)
        if args.out
        else checkpoint_path(
            demos_meta, args.reg, args.obs, args.seed, root=runs_dir(), initial_sigma=args.sigma, patience=args.patience
        )
    )


def cmd_demos(args) -> None:
    from vdtutorial.demos import SHIPPED_NOISE, generate_demos

    noise = SHIPPED_NOISE[args.task] if args.noise is None else args.noise
    out = output_path(args.out, demos_output(args), args.force)
    demos = generate_demos(args.task, args.samples, noise, args.seed, progress=progress_of(args))
    demos.save(out)
    print(
        f"{len(demos)} samples from {demos.meta['episodes']} noisy expert episodes "
        f"(noisy success rate {demos.meta['noisy_success_rate']:.2f})"
    )
    print(f"wrote {out}")


def cmd_expert(args) -> None:
    from vdtutorial.experiments.evaluation import expert_success_rate

    for task in args.task:
        rate, mean_len = expert_success_rate(task, args.episodes, seed=args.seed, progress=progress_of(args))
        print(
            f"expert {task}: success rate {rate:.3f} over {args.episodes} episodes "
            f"(mean episode length {mean_len:.2f} steps)"
        )


def _pretraining_method(name: str):
    """The table's entry of the method ``name`` (:mod:`vdtutorial.methods`), which must pre-train."""
    from vdtutorial.methods import METHODS, PARAMETER_SEPARATOR, method, pretraining_methods

    try:
        entry = method(name)
    except ValueError as exc:
        if name.partition(PARAMETER_SEPARATOR)[0] in METHODS:  # a known method with a wrong or missing number
            raise CommandError(f"--reg {name}: {exc}") from None
        entry = None
    if entry is None or not entry.pretrains:
        raise CommandError(f"--reg {name}: not a pre-training method (they are {', '.join(pretraining_methods())})")
    if entry.network_of is not None:
        raise CommandError(
            f"--reg {name}: starts from the {entry.network_of} network: pretrain --reg {entry.network_of}"
        )
    return entry


def cmd_pretrain(args) -> None:
    import torch

    from vdtutorial.demos import Demos
    from vdtutorial.experiments.checkpoints import (
        CheckpointError,
        checkpoint_path,
        default_config,
        load_checkpoint,
        pretrain_command,
        save_checkpoint,
        with_held_out_stop,
    )
    from vdtutorial.analysis.sparsity import sparsity_report
    from vdtutorial.experiments.initial_sigma import pretrain_with_sigma
    from vdtutorial.experiments.paths import runs_dir

    entry = _pretraining_method(args.reg)
    device = device_of(args)  # before any work
    torch.set_num_threads(1)
    demos = Demos.load(args.demos)
    config = default_config(args.reg, args.obs)
    if args.patience:  # --epochs is then the cap; VD's KL warm-up keeps its length in epochs
        config = with_held_out_stop(config, args.epochs or config.epochs, args.patience)
    elif args.epochs:
        config = dataclasses.replace(config, epochs=args.epochs)
    config = dataclasses.replace(config, initial_sigma=args.sigma)
    out = output_path(args.out, pretrain_output(args, demos.meta), args.force)
    spread_net = None
    follows = entry.spread_from
    if config.initial_sigma == "spread" and follows not in (None, args.reg):  # no noise model: follow another's
        # its checkpoint pre-trained alike (same data, seed and stop), shipped or made by pretrain --reg FOLLOWS
        paths = [
            checkpoint_path(demos.meta, follows, args.obs, args.seed, root=root, patience=args.patience)
            for root in (None, runs_dir())
        ]
        try:
            spread_net = load_checkpoint(next((p for p in paths if p.exists()), paths[0]), variational=True).mu
        except CheckpointError as exc:
            raise CommandError(
                f"--sigma spread for {args.reg} follows the {follows} network pre-trained alike: {exc}"
            ) from exc
    policy, history = pretrain_with_sigma(
        demos, config, seed=args.seed, progress=progress_of(args), spread_net=spread_net, device=device
    )
    command = (
        pretrain_command(args.reg, args.demos, args.seed, args.obs, config.initial_sigma)
        + (f" --epochs {args.epochs}" if args.epochs else "")
        + (f" --patience {args.patience}" if args.patience else "")
        + (f" --device {args.device}" if args.device != "cpu" else "")
    )
    save_checkpoint(policy, out, {"command": command})
    kept = history[-1]
    if args.patience:
        info = policy.pretrain_info
        kept = history[info["best_epoch"] - 1]
        print(
            f"stopped on the held-out MSE after {info['epochs_run']} of at most {config.epochs} epochs; "
            f"mu is epoch {info['best_epoch']}'s"
        )
    print(f"held-out imitation MSE {kept['val_mse']:.4f}")
    if entry.variational:
        print(sparsity_report(policy.mu))
    print(f"wrote {out}")


def cmd_evaluate(args) -> None:
    """The covariate-shift check before any RL (Section III-A): pre-trained policies vs the expert."""
    import gymnasium as gym
    import numpy as np

    from vdtutorial.demos import Demos
    from vdtutorial.envs import ENV_IDS
    from vdtutorial.experiments.evaluation import ExpertController, PolicyController, successes_per_episode
    from vdtutorial.experiments.checkpoints import checkpoint_path, load_checkpoint
    from vdtutorial.settings import budget

    demos = Demos.load(args.demos)
    task = demos.meta["task"]
    folder = Path(args.checkpoints) if args.checkpoints else data_dir() / "checkpoints"
    controllers = {
        reg: PolicyController(load_checkpoint(folder / checkpoint_path(demos.meta, reg, args.obs, args.seed).name))
        for reg in ("vd", "l2")
    }
    env = gym.make(ENV_IDS[task], obs_mode=args.obs)
    episodes = args.episodes or budget(5, 2)
    controllers["expert"] = ExpertController(env)
    for name, controller in controllers.items():
        runs = [successes_per_episode(env, controller, seed=100 + k) for k in range(episodes)]
        wins = np.array([r["successes"] for r in runs])
        reward = np.array([r["reward"] for r in runs])
        print(
            f"{name:7s} successes per 200-step episode {wins.mean():5.1f} +- {wins.std():4.1f}   "
            f"reward per episode {reward.mean():8.1f}   ({episodes} episodes, mean action)"
        )
    env.close()


def cmd_digits(args) -> None:
    from vdtutorial.experiments.digits import digits_validation

    result = digits_validation(seed=args.seed)
    print(
        f"dense MLP accuracy {result.dense_accuracy:.4f}; sparse VD MLP accuracy {result.vd_accuracy:.4f} "
        f"with {result.fraction_pruned:.1%} of weights pruned ({result.seconds:.1f} s)"
    )
    print(result.report)


def cmd_dropout_rate(args) -> None:
    """The rate of binary dropout matched to VD (:mod:`vdtutorial.analysis.dropout_rate`) in each checkpoint, and
    their mean: the one rate of ``dropout@P`` for the checkpoints' data set."""
    from vdtutorial.analysis.dropout_rate import matched_dropout_rate
    from vdtutorial.experiments.checkpoints import CheckpointError, load_checkpoint

    rates, data_sets = [], set()
    for path in args.checkpoints:
        try:
            policy = load_checkpoint(path, variational=True)
        except CheckpointError as exc:
            raise CommandError(str(exc)) from exc
        demos = policy.pretrain_info.get("demos", {})
        data_sets.add(tuple(demos.get(key) for key in ("task", "samples", "noise", "seed")))
        rates.append(matched_dropout_rate(policy.mu))
        print(f"{path}: seed {policy.pretrain_info.get('seed')}, p = {rates[-1]:.4f}")
    if len(data_sets) != 1:
        raise CommandError(f"the checkpoints were cloned on {len(data_sets)} data sets: give those of one")
    task, samples, noise, draw = data_sets.pop()
    mean = sum(rates) / len(rates)
    print(
        f"{task}, {samples} demonstrations at Sigma {noise:g} (draw {draw}): mean over {len(rates)} checkpoints "
        f"p = {mean:.4f} (from {min(rates):.4f} to {max(rates):.4f}); binary dropout at that rate: dropout@{mean:.2f}"
    )


def cmd_bench(args) -> None:
    from vdtutorial.cli import bench
    from vdtutorial.experiments.pendulum import bench_trpo_pendulum
    from vdtutorial.runner.kernels import kernel_settings, pinned

    if args.what != "finetune" and (args.profile or args.device != "cpu"):
        raise CommandError(f"{'--profile' if args.profile else '--device'} is an option of bench finetune only")
    which = "pinned, --exact-kernels" if pinned() else "this CPU's own"
    print(f"CPU kernels: {kernel_settings()['torch_cpu_capability']} ({which})")
    if args.what == "trpo":
        bench_trpo_pendulum(seeds=args.seeds, total_steps=args.steps)
    elif args.what == "finetune":
        bench.bench_finetune(profile=args.profile, device=device_of(args))
    else:
        {"env": bench.bench_env, "policy": bench.bench_policy}[args.what]()


def cmd_reproduce(args) -> None:
    """The package's main job: the whole pipeline at small scale (see experiments.reproduce_quick)."""
    from vdtutorial.experiments import reproduce_quick

    _print_summary(reproduce_quick(out=args.out, workers=args.workers, quick=args.quick))


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
        raise CommandError(
            f"{name} fine-tunes with the paper's TRPO settings: --fvp-subsample is an option of the figures"
        )
    if args.device != "cpu":
        raise CommandError(f"{name} runs on the CPU: --device is an option of the figures")
    options = dict(
        seeds=args.seeds,
        steps=args.steps,
        out=args.out,
        workers=args.workers,
        backend=backend,
        address=args.address,
        restart=args.restart,
        state_dir=args.state_dir,
    )
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

    fixed = [
        flag
        for flag, value in (
            ("--steps", args.steps),
            ("--obs", None if args.obs == "state" else args.obs),
            ("--fvp-subsample", args.fvp_subsample),
            ("--checkpoint-every", args.checkpoint_every),
            ("--device", None if args.device == "cpu" else args.device),
        )
        if value is not None
    ]
    if fixed:
        raise CommandError(f"{args.name} sets {', '.join(fixed)} itself (it compares {GRID_ONLY[args.name]})")
    try:
        record = pretrain_stop(
            seeds=args.seeds,
            out=args.out,
            workers=args.workers,
            backend=backend,
            address=args.address,
            restart=args.restart,
            state_dir=args.state_dir,
        )
    except ResumeError as exc:
        raise CommandError(str(exc)) from exc
    print(format_comparison(record))


def _figure_options(args) -> dict:
    """The options only the figures have (which methods, which data sets, which draw of them), checked before
    anything runs: a one-line error for another experiment or a method or data set the figure does not have."""
    from vdtutorial.demos import demo_command, demo_path
    from vdtutorial.experiments.figures import FIGURES, figure_data_sets, figure_methods
    from vdtutorial.experiments.paths import recorded_path
    from vdtutorial.methods import method

    options = {"methods": args.methods, "samples": args.samples, "sigmas": args.sigmas, "demo_seed": args.demo_seed}
    given = [f"--{key.replace('_', '-')}" for key, value in options.items() if value not in (None, 0)]
    if args.name not in FIGURES:
        if given:
            raise CommandError(
                f"{' and '.join(given)} {'are options' if len(given) > 1 else 'is an option'} of the figures"
            )
        return {}
    try:
        figure_methods(args.name, args.methods)
        datasets = figure_data_sets(args.name, args.samples, args.sigmas)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    task = FIGURES[args.name][2]
    missing = [
        (n, sigma) for n, sigma in datasets if args.demo_seed and not demo_path(task, n, sigma, args.demo_seed).exists()
    ]
    if missing and any(method(m).pretrains for m in figure_methods(args.name, args.methods)):
        n, sigma = missing[0]
        raise CommandError(
            f"no demonstrations of seed {args.demo_seed} for {n} samples at Sigma {sigma:g}: make them with "
            f"{demo_command(task, n, sigma, args.demo_seed)} "
            f"--out {recorded_path(demo_path(task, n, sigma, args.demo_seed))}"
        )
    return options


def cmd_experiment(args) -> None:
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
    figure_options = _figure_options(args)
    if args.name in PRE_RL_ONLY:
        ignored = [
            flag
            for flag, value in (
                ("--steps", args.steps),
                ("--fvp-subsample", args.fvp_subsample),
                ("--state-dir", args.state_dir),
                ("--checkpoint-every", args.checkpoint_every),
                ("--restart", args.restart or None),
                ("--device", None if args.device == "cpu" else args.device),
            )
            if value is not None
        ]
        if ignored:
            raise CommandError(
                f"{args.name} {PRE_RL_ONLY[args.name]}: {', '.join(ignored)} "
                f"{'are options' if len(ignored) > 1 else 'is an option'} of the figures"
            )
        experiments.table1(
            obs_mode=args.obs,
            seeds=args.seeds or (0,),
            kl_weighting=args.kl_weighting,
            out=args.out,
            workers=args.workers,
            backend=backend,
            address=args.address,
        )
        return
    if args.name in STATE_ONLY:
        _state_only(args, backend)
        return
    if args.name in GRID_ONLY:
        _grid_only(args, backend)
        return
    device_of(args)  # refused before any run starts
    trpo_config = None
    if args.fvp_subsample is not None:
        trpo_config = dataclasses.replace(experiments.default_trpo_config(), fvp_subsample=args.fvp_subsample)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            result = getattr(experiments, args.name)(
                seeds=args.seeds,
                total_steps=args.steps,
                obs_mode=args.obs,
                out=args.out,
                workers=args.workers,
                trpo_config=trpo_config,
                backend=backend,
                address=args.address,
                state_dir=args.state_dir,
                restart=args.restart,
                device=args.device,
                **figure_options,
                **resumable,
            )
        except experiments.ResumeError as exc:
            raise CommandError(str(exc)) from exc
    _print_summary(result)


def cmd_notebooks(args) -> None:
    """The chapters and the data they load, written into a folder of the learner's (see vdtutorial.course.chapters)."""
    from vdtutorial.course.chapters import EditedFilesError, NoNbgraderError, write_notebooks

    try:
        book = write_notebooks(args.dest, force=args.force, student=args.student)
    except (EditedFilesError, NoNbgraderError) as exc:
        raise CommandError(str(exc)) from exc
    edition = "the student edition of " if args.student else ""
    print(
        f"wrote {edition}{book.chapters} chapters, {book.appendices} appendices and {book.data_files} data files into "
        f"{book.dest}; start with "
        f"jupyter lab {book.dest / 'notebooks' / '00_start_here.ipynb'}"
    )
    if book.solutions:
        print(
            f"the {book.solutions} chapters with every exercise solved are in {book.dest / 'solutions'}: "
            "open them when you have tried"
        )


def cmd_book(args) -> None:
    """The chapters executed and exported as a static HTML book that reads offline (see vdtutorial.course.html_book)."""
    from vdtutorial.course.html_book import build_book

    start = time.perf_counter()
    book = build_book(args.out, numbers=args.chapters, quick=not args.full)
    print(f"wrote {len(book.chapters)} chapters in {time.perf_counter() - start:.0f} s; open {book.index}")


def cmd_claims(args) -> None:
    """The paper's claims as effect sizes with 95% intervals, from an experiment's rows (see experiments.effects)."""
    from vdtutorial.experiments import write_claims

    for folder in args.folders:
        if not Path(folder).is_dir() or not list(Path(folder).glob("*.json")):
            raise CommandError(f"{folder} is not an experiment folder (python -m vdtutorial experiment ... writes one)")
        try:
            table = write_claims(folder)
        except ValueError as exc:
            raise CommandError(str(exc)) from exc
        print(f"{folder}:\n{table}\n")


def cmd_rederive(args) -> None:
    """An experiment's figure and JSON summary re-written from its rows (see experiments.results.rederive; the
    experiments beyond the figures, whose records have a shape of their own, by their own rederive)."""
    from vdtutorial.experiments import beyond, format_summary, free_choices, merge_seeds, rederive

    own = {
        "beyond": (beyond.rederive_beyond, beyond.format_summary),
        "free_choices": (free_choices.rederive_free_choices, free_choices.format_table),
    }
    records = {}
    for folder in args.folders + args.add + args.add_other_cpu:
        if not Path(folder).is_dir() or not list(Path(folder).glob("*.json")):
            raise CommandError(f"{folder} is not an experiment folder (python -m vdtutorial experiment ... writes one)")
        records[folder] = json.loads(next(Path(folder).glob("*.json")).read_text())
    names = {folder: record.get("experiment") for folder, record in records.items()}
    if (args.add or args.add_other_cpu or args.plan) and len(args.folders) != 1:
        raise CommandError("--add and --plan take one experiment folder: name one")
    if (args.add or args.add_other_cpu) and (args.plan or records[args.folders[0]].get("plan")):
        raise CommandError(
            f"{args.folders[0]} holds a pre-registered plan's runs: its stopping rule adds no seeds after the runs"
        )
    if (args.add or args.add_other_cpu or args.plan) and set(names.values()) & set(own):
        raise CommandError(
            f"--add and --plan are for the figures' records: {', '.join(sorted(set(names.values()) & set(own)))} "
            "takes more seeds by running it again with them, and has no plan"
        )
    for other in args.add:
        merge_seeds(args.folders[0], other)
    for other in args.add_other_cpu:
        merge_seeds(args.folders[0], other, other_cpu=True)
    for folder in args.folders:
        remake, summary = own.get(names[folder], (rederive, format_summary))
        try:
            result = remake(folder, plan=args.plan) if args.plan else remake(folder)
        except ValueError as exc:
            raise CommandError(str(exc)) from exc
        print(summary(result))


def cmd_ablations(args) -> None:
    """The ablations' record from the plan's two folders (:mod:`vdtutorial.experiments.ablation_record`), refused
    in one line when a folder is missing or a run of the plan is missing or short of its budget."""
    from vdtutorial.experiments.ablation_record import NAME, ablation_record
    from vdtutorial.experiments.results import default_out

    out = Path(args.out) if args.out else default_out(NAME)
    try:
        record = ablation_record([args.runs_fig6, args.runs_fig5], out)
    except (ValueError, OSError) as exc:
        raise CommandError(str(exc)) from exc
    for claim in record["claims"]:
        print(
            f"{claim['text']}: {claim['estimate']:+.3g} ({claim['low']:+.3g} to {claim['high']:+.3g}), "
            f"p = {claim['p_value']:.2g}, {claim['verdict']}; Holm: {claim['holm_verdict']}"
        )
    for sentence in record["reading"].values():
        print(f"reading: {sentence}")
    print(f"wrote {out}")
