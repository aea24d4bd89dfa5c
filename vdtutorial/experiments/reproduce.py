"""The whole pipeline, small: the package's main job (``python -m vdtutorial reproduce``). Taught in chapter 00."""
from __future__ import annotations

from pathlib import Path

from vdtutorial.analysis.sparsity import sparsity_report
from vdtutorial.demos import DemoFileError, Demos, demo_command, demo_path, generate_demos
from vdtutorial.experiments.curves import Curve, vd_reaches_l2_final
from vdtutorial.experiments.jobs import RunSpec
from vdtutorial.experiments.results import ExperimentResult, run_experiment
from vdtutorial.experiments.pipeline import pretrained_policy
from vdtutorial.experiments.runs import RL_METHODS
from vdtutorial.methods import METHOD_LABELS, method
from vdtutorial.pretrain import PretrainConfig
from vdtutorial.runner.progress import live_by_default
from vdtutorial.experiments.paths import runs_dir
from vdtutorial.settings import budget

def reproduce_quick(out=None, seeds=(0, 1, 2), samples: int | None = None, noise: float = 0.5,
                    epochs: int | None = None, total_steps: int | None = None, workers: int = 2,
                    progress: bool | None = None) -> ExperimentResult:
    """The paper's pipeline end to end at a small scale, in a few minutes on 2 cores: generate a small
    reaching data set, pre-train VD and L2 on it, fine-tune VD, L2 and no pre-training with TRPO, and
    draw the Fig. 4-style curves. There is no expert line: it would cost a worker ~40 s, and at ~75
    successes per episode it would flatten curves that are still in single digits at this budget. The
    VD policy's sparsity (``sparsity_report(policy.mu)``, seed ``seeds[0]``) is printed and written to
    ``sparsity.txt``; ``result.summary`` carries it and the fig4-style "steps to reach L2's final level".

    Everything -- demonstrations, checkpoints, results -- goes to ``out`` (default ``runs/reproduce_quick``
    beside ``data/``), so the shipped full-scale artefacts are never touched. Quick mode shrinks the
    defaults further. Like every grid it is resumable: run it again to continue an interrupted one.
    ``progress``: see :mod:`~vdtutorial.runner.progress` (each step and each finished run prints a
    line unless it is False)."""
    out = Path(out) if out is not None else runs_dir() / "reproduce_quick"
    samples = budget(2000, 300) if samples is None else samples
    epochs = budget(60, 4) if epochs is None else epochs
    total_steps = budget(50_000, 1_000) if total_steps is None else total_steps
    path = demo_path("reach", samples, noise, 0, root=out)
    try:
        Demos.load(path, task="reach", samples=samples, noise=noise, seed=0)
    except DemoFileError:  # missing, corrupt or another set: make it
        if progress is not False:
            print(f"reproduce: generating {samples} demonstrations (Sigma = {noise:g}) into {path}", flush=True)
        live = live_by_default() if progress is None else progress
        generate_demos("reach", samples, noise, 0, progress=live).save(path)
    config = PretrainConfig(epochs=epochs)
    specs = [RunSpec(m, "reach", *((samples, noise) if method(m).pretrains else (None, None)), seed, "state",
                     total_steps, METHOD_LABELS[m]) for m in RL_METHODS for seed in seeds]
    command = (f"python -c 'from vdtutorial.experiments import reproduce_quick; reproduce_quick(out={str(out)!r}, "
               f"seeds={tuple(seeds)}, samples={samples}, noise={noise}, epochs={epochs}, total_steps={total_steps})'"
               f"  # demonstrations: {demo_command('reach', samples, noise, 0)} --out {path}")

    def summarise(curves: dict[str, Curve]) -> dict:
        report = sparsity_report(pretrained_policy("vd", Demos.load(path), "state", seeds[0], config, out).mu)
        (out / "sparsity.txt").write_text(f"{report}\n")
        print(report)
        return {"neuron_fraction": report.neuron_fraction, "weight_fraction": report.weight_fraction,
                "vd_reaches_l2_final": vd_reaches_l2_final(curves)}

    title = f"Quick reproduction: reaching, {samples} demos"
    return run_experiment("reproduce_quick", specs, title, out, workers, demos_root=out, checkpoints_root=out,
                          pretrain_config=config, command=command, summarise=summarise, progress=progress)
