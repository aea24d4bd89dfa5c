"""Benchmarks a learner waits for, run on the machine at hand (``python -m vdtutorial bench ...``).

``env``: environment steps per second for each task x observation mode x image size, in one process
and with two worker processes (gymnasium's AsyncVectorEnv), and the IK expert's time per action.
``policy``: network and pre-training cost (:func:`bench_policy`).
``finetune``: TRPO fine-tuning throughput end to end, rollouts + updates (:func:`bench_finetune`).
``trpo``: our TRPO against sb3-contrib's on gymnasium's Pendulum-v1
(:func:`vdtutorial.experiments.pendulum.bench_trpo_pendulum`).

Not taught in a chapter: measurements of this machine, whose numbers docs/results.md and docs/install.md quote.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import torch

from vdtutorial.baselines import LinearFeatureBaseline
from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert
from vdtutorial.fast.fisher import gauss_newton_fvp
from vdtutorial.fast.policy import fast_policy
from vdtutorial.policy import make_policy
from vdtutorial.settings import budget
from vdtutorial.trpo import TRPO
from vdtutorial.trust_region import double_backward_fvp

#: (task, obs_mode, image_size) rows of the env benchmark.
ENV_CASES = (
    ("reach", "state", 128),
    ("reach", "rgbd", 64),
    ("reach", "rgbd", 128),
    ("grasp", "state", 256),
    ("grasp", "rgbd", 128),
    ("grasp", "rgbd", 256),
)


def _make(task: str, obs_mode: str, image_size: int):
    return lambda: gym.make(ENV_IDS[task], obs_mode=obs_mode, image_size=image_size)


def env_steps_per_second(
    task: str, obs_mode: str, image_size: int, steps: int, workers: int = 1, seed: int = 0
) -> float:
    """Random-action steps per second; with ``workers > 1`` an AsyncVectorEnv of that many envs
    (each vector step counts ``workers`` env steps)."""
    rng = np.random.default_rng(seed)
    if workers == 1:
        env = _make(task, obs_mode, image_size)()
        env.reset(seed=seed)
        start = time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(rng.uniform(-0.6, 0.6, 6))
            if term or trunc:
                env.reset()
        elapsed = time.perf_counter() - start
        env.close()
        return steps / elapsed
    venv = gym.vector.AsyncVectorEnv([_make(task, obs_mode, image_size)] * workers)
    venv.reset(seed=seed)
    n = max(1, steps // workers)
    start = time.perf_counter()
    for _ in range(n):
        venv.step(rng.uniform(-0.6, 0.6, (workers, 6)))
    elapsed = time.perf_counter() - start
    venv.close()
    return n * workers / elapsed


def expert_timing(task: str, episodes: int, seed: int = 0) -> dict:
    """Mean time of one expert action (eqs. 9-10) and of building G for a cup, in milliseconds."""
    env = gym.make(ENV_IDS[task], obs_mode="state")
    expert = IKExpert(env)
    t_action = t_set = 0.0
    n_actions = 0
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        start = time.perf_counter()
        expert.reset()
        t_set += time.perf_counter() - start
        while True:
            start = time.perf_counter()
            a = expert.action()
            t_action += time.perf_counter() - start
            n_actions += 1
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                break
    env.close()
    return {"action_ms": 1e3 * t_action / n_actions, "solution_set_ms": 1e3 * t_set / episodes}


def bench_env(steps: int | None = None) -> list[dict]:
    """All rows of the env benchmark, printed as they come."""
    steps = steps or budget(3000, 300)
    rows = []
    print(f"{'task':6} {'obs':6} {'size':>5} {'1 proc steps/s':>15} {'2 workers steps/s':>18}")
    for task, obs_mode, size in ENV_CASES:
        one = env_steps_per_second(task, obs_mode, size, steps)
        two = env_steps_per_second(task, obs_mode, size, steps, workers=2)
        rows.append(
            {"task": task, "obs_mode": obs_mode, "image_size": size, "steps_per_s": one, "steps_per_s_2workers": two}
        )
        print(f"{task:6} {obs_mode:6} {size:>5} {one:>15.0f} {two:>18.0f}", flush=True)
    for task in ENV_IDS:
        t = expert_timing(task, budget(50, 5))
        rows.append({"task": task, "expert": True, **t})
        print(f"expert {task}: {t['action_ms']:.3f} ms per action, {t['solution_set_ms']:.1f} ms to build G per cup")
    return rows


def _best_time(fn, repeats: int) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _network_times(net, obs, repeats: int) -> tuple[float, float]:
    """Best forward and forward+backward time of ``net`` on a batch."""
    import torch

    def forward():
        with torch.no_grad():
            net(obs)

    def forward_backward():
        net.zero_grad()
        net(obs).square().mean().backward()

    return _best_time(forward, repeats), _best_time(forward_backward, repeats)


def bench_policy(samples: int | None = None, repeats: int | None = None) -> list[dict]:
    """Cost of the mu network for a batch of 200 observations, plain vs sparse VD (training mode, local
    reparameterisation) vs the compacted pruned network, for state and rgbd 128x128 inputs; then one
    pre-training epoch over ``samples`` demonstrations (state inputs; rgbd images re-rendered first).

    The compacted network comes from a VD policy pre-trained on the shipped 8000-sample reach set (the
    shipped checkpoint when present; else trained here for the state network, and for the rgbd network
    the untrained VD network is compacted, which removes almost nothing -- the row says so)."""
    import torch

    from vdtutorial.demos import Demos, demo_path
    from vdtutorial.experiments.checkpoints import checkpoint_path, load_checkpoint
    from vdtutorial.pretrain import PretrainConfig, demo_observations, observation_space, pretrain
    from vdtutorial.policy import obs_to_tensor
    from vdtutorial.analysis.compact import compact
    from vdtutorial.analysis.sparsity import sparsity_report

    torch.set_num_threads(1)
    samples = samples or budget(8000, 400)
    repeats = repeats or budget(10, 2)
    demos = Demos.load(demo_path("reach", 8000, 0.5, 0))
    rows = []
    print(f"{'obs':6} {'network':26} {'forward ms':>11} {'fwd+bwd ms':>11} {'weights':>9}")
    for obs_mode in ("state", "rgbd"):
        space = observation_space("reach", obs_mode, 128)
        obs = obs_to_tensor(demo_observations(demos, obs_mode, 128, indices=np.arange(200)))
        torch.manual_seed(0)
        plain = make_policy(space, 6, variational=False).mu
        vd = make_policy(space, 6, variational=True).mu.train()
        ckpt = checkpoint_path(demos.meta, "vd", obs_mode, 0)
        if ckpt.exists():
            trained = load_checkpoint(ckpt).mu
            source = f"shipped {ckpt.name}"
        elif obs_mode == "state":
            trained = pretrain(demos, PretrainConfig(reg="vd", epochs=budget(150, 3)), progress=False)[0].mu
            source = "pre-trained here"
        else:
            trained = make_policy(space, 6, variational=True).mu.eval()
            source = "untrained VD net (no checkpoint)"
        small = compact(trained.eval())
        for name, net in (("plain", plain), ("sparse VD (train mode)", vd), ("compacted pruned", small)):
            fwd, fb = _network_times(net, obs, repeats)
            n_weights = sum(p.numel() for n, p in net.named_parameters() if n.endswith("weight"))
            row = {"obs_mode": obs_mode, "network": name, "forward_ms": 1e3 * fwd, "forward_backward_ms": 1e3 * fb}
            rows.append({**row, "weights": n_weights})
            print(f"{obs_mode:6} {name:26} {1e3 * fwd:>11.2f} {1e3 * fb:>11.2f} {n_weights:>9d}")
        report = sparsity_report(trained)
        pruned = f"{report.weight_fraction:.1%} weights, {report.neuron_fraction:.1%} neurons pruned"
        print(f"       compacted from: {source}; {pruned}")
    for obs_mode in ("state", "rgbd"):
        part = Demos(
            **{k: getattr(demos, k)[:samples] for k in ("joints", "cup", "actions", "episode", "t")},
            meta={**demos.meta, "samples": samples},
        )
        obs = demo_observations(part, obs_mode, 128)
        for reg in ("l2", "vd"):
            start = time.perf_counter()
            config = PretrainConfig(reg=reg, obs_mode=obs_mode, epochs=1, val_fraction=0.0)
            pretrain(part, config, progress=False, observations=obs)
            seconds = time.perf_counter() - start
            rows.append({"obs_mode": obs_mode, "epoch": reg, "samples": samples, "seconds": seconds})
            print(f"one pre-training epoch, {obs_mode}, {reg}, {samples} samples: {seconds:.2f} s")
    return rows


#: (label, Fisher-vector product, fvp_subsample) of the fine-tuning benchmark's rows, per observation mode.
FINETUNE_CASES = (
    ("double backward", "double_backward", 1.0),  # the library's defaults: plain policy, chapter 06's product
    ("Gauss-Newton", "gauss_newton", 1.0),  # the experiments' options: vdtutorial.fast's policy and product
    ("Gauss-Newton", "gauss_newton", 0.1),  # the same on a 10% subsample, a control
)
#: The products the cases name, as ``TRPO(fvp=...)`` takes them.
FISHER_PRODUCTS = {"double_backward": double_backward_fvp, "gauss_newton": gauss_newton_fvp}
#: The parts of a TRPO update that :class:`UpdateClock` times, in the order the update runs them.
UPDATE_PARTS = ("gradient", "fisher_setup", "cg_products", "line_search", "baseline")


class UpdateClock:
    """The CPU seconds (less machine-dependent than wall time) of the parts of one TRPO update, timed from outside
    through what TRPO is given: its Fisher-vector product (:meth:`fvp`), its baseline (:meth:`baseline`) and the
    update's start (:class:`PartTimedTRPO`). Between those marks lie the surrogate gradient (with the forward pass
    at theta_old), the Fisher setup, the CG products, the line search and the baseline fit (:data:`UPDATE_PARTS`)."""

    def __init__(self):
        self.marks: dict[str, float] = {}

    def mark(self, name: str) -> None:
        self.marks[name] = time.process_time()

    def fvp(self, product):
        """``product`` (a ``TRPO(fvp=...)``) with its setup and its last product call marked."""

        def timed_product(policy, params, obs, old, damping, dist=None):
            self.mark("fisher_setup")
            fisher = product(policy, params, obs, old, damping, dist)
            self.mark("cg_products")

            def timed_fisher(v: torch.Tensor) -> torch.Tensor:
                result = fisher(v)
                self.mark("line_search")  # the line search starts after the last product
                return result

            return timed_fisher

        return timed_product

    def baseline(self, baseline) -> "TimedBaseline":
        """``baseline`` with its fit marked."""
        return TimedBaseline(baseline, self)

    def split(self) -> dict[str, float]:
        """The last update's parts, CPU seconds each (the time between one part's mark and the next's)."""
        order = [*UPDATE_PARTS, "end"]
        return {part: self.marks[after] - self.marks[part] for part, after in zip(order, order[1:])}


class TimedBaseline:
    """A TRPO baseline whose ``fit`` marks the start and the end of the update's last part (:class:`UpdateClock`)."""

    def __init__(self, baseline, clock: UpdateClock):
        self.inner = baseline
        self.clock = clock

    def predict(self, features, timesteps):
        return self.inner.predict(features, timesteps)

    def fit(self, features, timesteps, returns):
        self.clock.mark("baseline")
        self.inner.fit(features, timesteps, returns)
        self.clock.mark("end")

    def state_dict(self) -> dict:
        return self.inner.state_dict()

    def load_state_dict(self, state: dict) -> None:
        self.inner.load_state_dict(state)


class PartTimedTRPO(TRPO):
    """TRPO whose updates are timed by parts (:class:`UpdateClock`): the clock's Fisher product and baseline wrap
    the ones given, and :meth:`update` marks its start. The algorithm is TRPO's own, unchanged."""

    def __init__(self, policy, env, config, fvp, device, seed: int = 0):
        self.clock = UpdateClock()
        super().__init__(
            policy,
            env,
            config,
            seed=seed,
            fvp=self.clock.fvp(fvp),
            device=device,
            baseline=self.clock.baseline(LinearFeatureBaseline(config.baseline_reg)),
        )

    def update(self, batch):
        self.clock.mark("gradient")
        return super().update(batch)

    @property
    def update_split(self) -> dict[str, float]:
        """CPU seconds of the last update's parts (:data:`UPDATE_PARTS`)."""
        return self.clock.split()


def bench_finetune(
    iterations: int | None = None, profile: bool = False, device: torch.device | str = "cpu"
) -> list[dict]:
    """TRPO fine-tuning of the pruned VD reach policy (8000 demonstrations, Sigma = 0.5, seed 0), state
    and rgbd 128 x 128, in one process with one torch thread: seconds per 200-step iteration spent
    collecting (rendering + policy) and updating, env steps per second end to end (wall clock, and per
    second of this process's CPU time, which depends less on other load on the machine), and the mean
    KL and accepted step fraction of the updates. One row per :data:`FINETUNE_CASES` entry: the exact
    Fisher-vector products on the whole batch by double backward with the plain policy (the library's
    defaults), and in Gauss-Newton form with :mod:`vdtutorial.fast`'s policy (the experiments' options), then
    the latter on a 10% subsample. The cases of one observation mode take turns iteration by
    iteration (each with its own policy and the same seeds), so that a change in the machine's load
    affects them alike; the speed-up of the Gauss-Newton form on the whole batch is printed after
    them. One warm-up iteration each, then ``iterations`` timed ones (default 10; quick mode 2).

    A second table splits each case's update into its parts, in CPU seconds per iteration, timed from outside
    the update (:class:`UpdateClock`): the surrogate gradient (with the forward pass at theta_old), the Fisher
    setup, the CG products, the line search and the baseline fit. With ``profile``, the rgbd whole-batch
    Gauss-Newton case then runs ``iterations`` more under the profilers (:func:`print_profile`).

    ``device``: where the updates run (``TRPO(device=...)``; "cuda": a GPU). The rollouts stay on the CPU, so
    the collect column does not change; the update column is wall time with the GPU, and the CPU-time columns
    (steps per CPU second, the update split) count what this process spent, waiting for the GPU included."""
    import torch

    from vdtutorial.demos import Demos, demo_path
    from vdtutorial.experiments import NUM_ENVS, finetune_policy
    from vdtutorial.experiments.checkpoints import checkpoint_path, default_config, load_checkpoint
    from vdtutorial.pretrain import PretrainConfig
    from vdtutorial.rollout import make_vec_env
    from vdtutorial.trpo import TRPOConfig

    iterations = iterations or budget(10, 2)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    demos = Demos.load(demo_path("reach", 8000, 0.5, 0))
    rows = []
    print(
        f"{'obs':6} {'Fisher product':16} {'fvp_subsample':>13} {'collect s':>10} {'update s':>9} {'steps/s':>8} "
        f"{'steps/cpu s':>11} {'mean KL':>8} {'step fraction':>13}"
    )
    for obs_mode in ("state", "rgbd"):
        env = make_vec_env(ENV_IDS["reach"], NUM_ENVS, obs_mode=obs_mode, image_size=128)
        # the shipped checkpoint with its own settings (any mode), else one pre-trained now with the defaults
        ckpt = checkpoint_path(demos.meta, "vd", obs_mode, 0)
        config = (
            PretrainConfig(**load_checkpoint(ckpt).pretrain_info["config"])
            if ckpt.exists()
            else default_config("vd", obs_mode)
        )
        source = f"shipped {ckpt.name}" if ckpt.exists() else "pre-trained now (no shipped checkpoint)"
        runs = []
        for label, fisher, fvp_subsample in FINETUNE_CASES:
            torch.manual_seed(0)
            policy = finetune_policy("vd", env, demos, obs_mode, 0, config, checkpoints_root=ckpt.parent.parent)
            policy = fast_policy(policy) if fisher == "gauss_newton" else policy
            algo = PartTimedTRPO(policy, env, TRPOConfig(fvp_subsample=fvp_subsample), FISHER_PRODUCTS[fisher], device)
            runs.append((algo, []))
        for i in range(iterations + 1):
            for algo, timed in runs:  # every case collects from the shared env, reset with its own seeds
                cpu = time.process_time()
                row = algo.iterate()
                if i > 0:  # the first iteration warms up
                    timed.append((row, time.process_time() - cpu, algo.update_split))
        for (label, fisher, fvp_subsample), (algo, timed) in zip(FINETUNE_CASES, runs):
            row = {
                "obs_mode": obs_mode,
                "fisher": fisher,
                "fvp_subsample": fvp_subsample,
                "policy": source,
                **_finetune_summary(timed, algo.config.steps_per_iter),
            }
            rows.append(row)
            print(
                f"{obs_mode:6} {label:16} {fvp_subsample:>13g} {row['collect_s']:>10.3f} {row['update_s']:>9.3f} "
                f"{row['steps_per_s']:>8.1f} {row['steps_per_cpu_s']:>11.1f} {row['mean_kl']:>8.4f} "
                f"{row['step_fraction']:>13.3f}",
                flush=True,
            )
        _print_update_split(rows[-len(FINETUNE_CASES) :], [label for label, *_ in FINETUNE_CASES])
        old, new = rows[-len(FINETUNE_CASES) :][:2]
        print(
            f"       whole batch, Gauss-Newton / double backward: {new['steps_per_s'] / old['steps_per_s']:.2f}x env "
            f"steps/s ({new['steps_per_cpu_s'] / old['steps_per_cpu_s']:.2f}x per CPU second), update "
            f"{old['update_s'] / new['update_s']:.2f}x faster"
        )
        print(
            f"       policy: {source}, pruned; {iterations} iterations of 200 steps after one warm-up, per case; "
            f"updates on {torch.device(device)}"
        )
        if profile and obs_mode == "rgbd":
            print_profile(runs[FINETUNE_CASES.index(("Gauss-Newton", "gauss_newton", 1.0))][0], iterations)
        env.close()
    torch.set_num_threads(threads)
    return rows


def _finetune_summary(timed: list[tuple[dict, float, dict]], steps_per_iter: int) -> dict:
    """One fine-tuning case's columns from its timed iterations, (TRPO log row, CPU seconds, update split)
    each: the mean seconds collecting and updating per iteration, env steps per second of both together and
    per CPU second, the mean KL of the steps, the mean accepted fraction of the full step (0 when rejected),
    and the mean CPU seconds of each part of the update (``split_cpu_s``)."""
    rows = [row for row, *_ in timed]
    collect, update = sum(r["collect_s"] for r in rows), sum(r["update_s"] for r in rows)
    steps = len(rows) * steps_per_iter
    fractions = [0.0 if r["line_search"] == "rejected" else r["line_search"] for r in rows]
    splits = [split for *_, split in timed]
    return {
        "collect_s": collect / len(rows),
        "update_s": update / len(rows),
        "steps_per_s": steps / (collect + update),
        "steps_per_cpu_s": steps / sum(cpu for _, cpu, _ in timed),
        "mean_kl": float(np.mean([r["mean_kl"] for r in rows])),
        "step_fraction": float(np.mean(fractions)),
        "split_cpu_s": {part: float(np.mean([s[part] for s in splits])) for part in splits[0]},
    }


def _print_update_split(rows: list[dict], labels: list[str]) -> None:
    """The update's parts per case, CPU seconds per iteration (see :func:`bench_finetune`)."""
    parts = list(rows[0]["split_cpu_s"])
    print(f"       update split, CPU s per iteration: {'':16} {'':>13} " + " ".join(f"{p:>12}" for p in parts))
    for label, row in zip(labels, rows):
        print(
            f"{row['obs_mode']:6} {label:16} {row['fvp_subsample']:>13g} {'':>35}"
            + " ".join(f"{row['split_cpu_s'][p]:>12.3f}" for p in parts)
        )


def print_profile(algo: TRPO, iterations: int, top: int = 15) -> None:
    """Run ``iterations`` TRPO iterations of ``algo`` under torch's profiler and cProfile and print where
    the time went: the ``top`` torch operators by self CPU time (convolutions, matrix products, copies),
    then the ``top`` Python-level functions by their own time (the renderer, pybullet, the Python code)."""
    import cProfile
    import pstats

    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as torch_profile:
        for _ in range(iterations):
            algo.iterate()
    print(f"\nprofile: {iterations} iterations of the rgbd whole-batch Gauss-Newton case; torch operators")
    print(torch_profile.key_averages().table(sort_by="self_cpu_time_total", row_limit=top))
    python_profile = cProfile.Profile()
    python_profile.enable()
    for _ in range(iterations):
        algo.iterate()
    python_profile.disable()
    print(f"the same, {iterations} more iterations; Python functions by their own time")
    pstats.Stats(python_profile).sort_stats("tottime").print_stats(top)
