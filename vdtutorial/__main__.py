"""Command line: ``python -m vdtutorial COMMAND ...`` (``--help`` lists the commands)."""
from __future__ import annotations

import argparse
import dataclasses
import sys

from vdtutorial.settings import QUICK


def _cmd_demos(args) -> None:
    from vdtutorial.demos import SHIPPED_NOISE, demo_path, generate_demos

    noise = SHIPPED_NOISE[args.task] if args.noise is None else args.noise
    demos = generate_demos(args.task, args.samples, noise, args.seed, progress=not args.no_progress)
    out = demos.save(args.out or demo_path(args.task, args.samples, noise, args.seed))
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


def _cmd_evaluate(args) -> None:
    """The covariate-shift check before any RL (Section III-A): pre-trained policies vs the expert."""
    import gymnasium as gym
    import numpy as np

    from vdtutorial.demos import Demos
    from vdtutorial.envs import ENV_IDS
    from vdtutorial.evaluation import ExpertController, PolicyController, successes_per_episode
    from vdtutorial.pretrain import checkpoint_path, load_checkpoint
    from vdtutorial.settings import budget

    demos = Demos.load(args.demos)
    task = demos.meta["task"]
    env = gym.make(ENV_IDS[task], obs_mode=args.obs)
    episodes = args.episodes or budget(5, 2)
    controllers = {reg: PolicyController(load_checkpoint(checkpoint_path(demos.meta, reg, args.obs, 0)))
                   for reg in ("vd", "l2")}
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

    if args.what == "trpo":
        from vdtutorial.trpo import bench_trpo_pendulum

        bench_trpo_pendulum()
    else:
        {"env": bench.bench_env, "policy": bench.bench_policy, "finetune": bench.bench_finetune}[args.what]()


def _cmd_reproduce(args) -> None:
    """The package's main job: the whole pipeline at small scale (see experiments.reproduce_quick)."""
    from vdtutorial.experiments import reproduce_quick

    _print_summary(reproduce_quick(out=args.out, workers=args.workers))


def _print_summary(result) -> None:
    """Final level of every curve, the fig4-style "VD reaches L2" line if any, and where files went."""
    for label, final in result.summary["final"].items():
        print(f"{label:>32}: final {final['mean']:.2f} (95% band {final['low']:.2f} to {final['high']:.2f}, "
              f"{final['seeds']} seeds)")
    if "vd_reaches_l2_final" in result.summary:
        print(result.summary["vd_reaches_l2_final"]["text"])
    print(f"wrote {result.out}")


def _cmd_experiment(args) -> None:
    import warnings

    from vdtutorial import experiments

    if args.name == "table1":
        experiments.table1(obs_mode=args.obs, seed=args.seeds[0] if args.seeds else 0, out=args.out, workers=args.workers)
        return
    trpo_config = None
    if args.fvp_subsample is not None:
        trpo_config = dataclasses.replace(experiments.default_trpo_config(args.obs), fvp_subsample=args.fvp_subsample)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        result = getattr(experiments, args.name)(seeds=args.seeds, total_steps=args.steps, obs_mode=args.obs,
                                                 out=args.out, workers=args.workers, trpo_config=trpo_config)
    _print_summary(result)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m vdtutorial", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demos", help="generate expert demonstrations (eqs. 5-8)")
    p.add_argument("--task", choices=("reach", "grasp"), default="reach")
    p.add_argument("--samples", type=int, default=8000, help="state-action pairs in the data set")
    p.add_argument("--noise", type=float, default=None,
                   help="Sigma: std of the action noise, radians (default: the shipped sets', 0.5 reach, 0.03 grasp)")
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

    p = sub.add_parser("evaluate", help="successful trajectories per 200-step episode: pre-trained VD, L2, expert")
    p.add_argument("--demos", default="data/demos/reach_n8000_sigma0.5_seed0.npz")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state")
    p.add_argument("--episodes", type=int, default=None, help="200-step episodes per controller (default 5)")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("digits", help="validate sparse VD on scikit-learn's digits (dense vs VD MLP)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_digits)

    p = sub.add_parser("bench", help="benchmarks (env, policy, trpo)")
    p.add_argument("what", choices=("env", "policy", "finetune", "trpo"),
                   help="env: steps/s; policy: network and pre-training cost; finetune: TRPO fine-tuning steps/s "
                        "end to end; trpo: Pendulum-v1 vs sb3-contrib")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("experiment", help="the paper's experiments: fig4, fig5, fig6, fig7, table1")
    p.add_argument("name", choices=("fig4", "fig5", "fig6", "fig7", "table1"))
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="default: 0 1 2 (table1: the first seed)")
    p.add_argument("--steps", type=int, default=None, help="RL env steps per run (default: the paper's 3e5)")
    p.add_argument("--obs", choices=("state", "rgbd"), default="state")
    p.add_argument("--workers", type=int, default=2, help="runs in parallel (one per core)")
    p.add_argument("--out", default=None, help="output folder (default: data/results/NAME)")
    p.add_argument("--fvp-subsample", type=float, default=None,
                   help="fraction of each TRPO batch for the Fisher-vector products (default: 1 state, 0.1 rgbd)")
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
