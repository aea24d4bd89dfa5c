"""Command line: ``python -m vdtutorial COMMAND ...`` (``--help`` lists the commands)."""
from __future__ import annotations

import argparse
import dataclasses
import sys

from vdtutorial.settings import QUICK


def _cmd_demos(args) -> None:
    from vdtutorial.demos import demo_path, generate_demos

    demos = generate_demos(args.task, args.samples, args.noise, args.seed, progress=not args.no_progress)
    out = demos.save(args.out or demo_path(args.task, args.samples, args.noise, args.seed))
    print(f"{len(demos)} samples from {demos.meta['episodes']} noisy expert episodes "
          f"(noisy success rate {demos.meta['noisy_success_rate']:.2f})")
    print(f"wrote {out}")


def _cmd_expert(args) -> None:
    from vdtutorial.evaluation import expert_success_rate

    for task in args.task:
        rate, mean_len = expert_success_rate(task, args.episodes, seed=args.seed)
        print(f"expert {task}: success rate {rate:.3f} over {args.episodes} episodes "
              f"(mean episode length {mean_len:.2f} steps)")


def _cmd_pretrain(args) -> None:
    import torch

    from vdtutorial.demos import Demos
    from vdtutorial.pretrain import checkpoint_path, default_config, pretrain, pretrain_command, save_checkpoint
    from vdtutorial.vd import sparsity_report

    torch.set_num_threads(1)
    demos = Demos.load(args.demos)
    config = default_config(args.reg, args.obs)
    if args.epochs:
        config = dataclasses.replace(config, epochs=args.epochs)
    policy, history = pretrain(demos, config, seed=args.seed)
    command = pretrain_command(args.reg, args.demos, args.seed, args.obs) + (f" --epochs {args.epochs}" if args.epochs else "")
    out = save_checkpoint(policy, args.out or checkpoint_path(demos.meta, args.reg, args.obs, args.seed), {"command": command})
    print(f"held-out imitation MSE {history[-1]['val_mse']:.4f}")
    if args.reg == "vd":
        print(sparsity_report(policy.mu))
    print(f"wrote {out}")


def _cmd_bench(args) -> None:
    from vdtutorial import bench

    {"env": bench.bench_env, "policy": bench.bench_policy}[args.what]()


def _cmd_reproduce(args) -> None:
    """The package's main job: the whole pipeline at small scale (see experiments.reproduce_quick)."""
    from vdtutorial.experiments import reproduce_quick

    reproduce_quick(out=args.out, workers=args.workers)


def _cmd_experiment(args) -> None:
    import warnings

    from vdtutorial import experiments

    if args.name == "table1":
        experiments.table1(obs_mode=args.obs, seed=args.seeds[0] if args.seeds else 0, out=args.out, workers=args.workers)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        result = getattr(experiments, args.name)(seeds=args.seeds, total_steps=args.steps, obs_mode=args.obs,
                                                 out=args.out, workers=args.workers)
    for label, final in result.summary["final"].items():
        print(f"{label:>32}: final {final}")
    if "vd_reaches_l2_final" in result.summary:
        print(result.summary["vd_reaches_l2_final"]["text"])
    print(f"wrote {result.out}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m vdtutorial", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demos", help="generate expert demonstrations (eqs. 5-8)")
    p.add_argument("--task", choices=("reach", "grasp"), default="reach")
    p.add_argument("--samples", type=int, default=8000, help="state-action pairs in the data set")
    p.add_argument("--noise", type=float, default=0.5, help="Sigma: std of the action noise, radians")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="output file (default: data/demos/TASK_nN_sigmaS_seedK.npz)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_demos)

    p = sub.add_parser("expert", help="measure the IK expert's success rate")
    p.add_argument("--task", nargs="+", choices=("reach", "grasp"), default=["reach", "grasp"])
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_expert)

    p = sub.add_parser("pretrain", help="behavioural cloning with sparse VD or L2 (eqs. 1-4)")
    p.add_argument("--reg", choices=("vd", "l2"), required=True)
    p.add_argument("--demos", required=True, help="a demonstrations file (python -m vdtutorial demos ...)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--obs", choices=("state", "rgbd"), default="state")
    p.add_argument("--epochs", type=int, default=None, help="default: pretrain.default_config's setting")
    p.add_argument("--out", default=None, help="checkpoint file (default: data/checkpoints/...)")
    p.set_defaults(func=_cmd_pretrain)

    p = sub.add_parser("bench", help="benchmarks (env, policy)")
    p.add_argument("what", choices=("env", "policy"))
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("experiment", help="the paper's experiments: fig4, fig5, fig6, fig7, table1")
    p.add_argument("name", choices=("fig4", "fig5", "fig6", "fig7", "table1"))
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="default: 0 1 2 (table1: the first seed)")
    p.add_argument("--steps", type=int, default=None, help="RL env steps per run (default: the paper's 3e5)")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state")
    p.add_argument("--workers", type=int, default=2, help="runs in parallel (one per core)")
    p.add_argument("--out", default=None, help="output folder (default: data/results/NAME)")
    p.set_defaults(func=_cmd_experiment)

    p = sub.add_parser("reproduce", help="the main job: the whole pipeline at small scale (< 5 min on 2 cores)")
    p.add_argument("--quick", action="store_true", help="accepted for clarity; reproduce always runs small")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", default=None, help="output folder (default: runs/reproduce_quick)")
    p.set_defaults(func=_cmd_reproduce)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if QUICK:
        print("[quick mode: small budgets]", file=sys.stderr)
    args.func(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
