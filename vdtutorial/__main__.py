"""Command line: ``python -m vdtutorial COMMAND ...`` (``--help`` lists the commands)."""
from __future__ import annotations

import argparse
import sys

from vdtutorial.settings import QUICK, budget


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
    from vdtutorial.pretrain import PretrainConfig, checkpoint_path, pretrain, pretrain_command, save_checkpoint
    from vdtutorial.vd import sparsity_report

    torch.set_num_threads(1)
    demos = Demos.load(args.demos)
    config = PretrainConfig(reg=args.reg, obs_mode=args.obs, **({"epochs": args.epochs} if args.epochs else {}))
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
    """The package's main job (so far): the expert's success rates and a demonstrations data set."""
    from vdtutorial.demos import demo_path, generate_demos
    from vdtutorial.evaluation import expert_success_rate

    episodes = budget(200, 20)
    for task in ("reach", "grasp"):
        rate, mean_len = expert_success_rate(task, episodes, seed=args.seed)
        print(f"expert {task}: success rate {rate:.3f} over {episodes} episodes (mean length {mean_len:.2f} steps)")
    samples = budget(8000, 500)
    demos = generate_demos("reach", samples, 0.5, args.seed)
    print(f"wrote {demos.save(demo_path('reach', samples, 0.5, args.seed, root=args.out))}")


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
    p.add_argument("--epochs", type=int, default=None, help="default: the PretrainConfig setting")
    p.add_argument("--out", default=None, help="checkpoint file (default: data/checkpoints/...)")
    p.set_defaults(func=_cmd_pretrain)

    p = sub.add_parser("bench", help="benchmarks (env, policy)")
    p.add_argument("what", choices=("env", "policy"))
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("reproduce", help="the main job: expert success rates and a demonstrations set")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="data folder for the generated demonstrations")
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
