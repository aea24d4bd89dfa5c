"""The command line: each subcommand parses, and the cheap ones run end to end."""

import argparse
import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from vdtutorial.__main__ import build_parser, main
from vdtutorial.demos import Demos
from vdtutorial.settings import data_dir, is_quick

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(
    "command", ["demos", "expert", "pretrain", "evaluate", "digits", "bench", "experiment", "reproduce", "rederive"]
)
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage" in capsys.readouterr().out


def test_demos_command_writes_the_file_it_prints(tmp_path, capsys):
    out = tmp_path / "d.npz"
    main(
        [
            "demos",
            "--task",
            "reach",
            "--samples",
            "30",
            "--noise",
            "0.1",
            "--seed",
            "4",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed
    demos = Demos.load(out, task="reach", samples=30, noise=0.1, seed=4)
    assert len(demos) == 30


def test_expert_command_prints_success_rates(capsys):
    main(["expert", "--task", "reach", "--episodes", "3"])
    assert "expert reach: success rate 1.000 over 3 episodes" in capsys.readouterr().out


def test_bad_arguments_are_refused():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["demos", "--task", "push"])
    with pytest.raises(SystemExit):
        build_parser().parse_args(["experiment", "fig9"])


@pytest.mark.skipif(not is_quick(), reason="the full-size main job takes minutes; CI runs it in quick mode")
def test_reproduce_runs_the_whole_pipeline(tmp_path, capsys):
    main(["reproduce", "--quick", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    for label in ("VD: final", "L2: final", "no pre-training: final", f"wrote {tmp_path}"):
        assert label in printed
    assert (tmp_path / "reproduce_quick.png").exists() and (tmp_path / "sparsity.txt").exists()
    assert len(list((tmp_path / "runs").glob("*.csv"))) == 9  # 3 methods x 3 seeds


@pytest.mark.skipif(not is_quick(), reason="pre-trains VD and L2 policies: quick mode keeps it to seconds")
def test_experiment_fvp_subsample_reaches_the_runs_and_the_record(tmp_path, capsys):
    main(
        [
            "experiment",
            "fig4",
            "--seeds",
            "0",
            "--steps",
            "200",
            "--fvp-subsample",
            "0.5",
            "--workers",
            "1",
            "--out",
            str(tmp_path),
        ]
    )
    assert "VD: final" in capsys.readouterr().out
    record = json.loads((tmp_path / "fig4.json").read_text())
    assert record["trpo_config"]["fvp_subsample"] == 0.5
    assert "--fvp-subsample 0.5" in record["command"]


def test_experiment_methods_runs_only_those_and_records_them(tmp_path, capsys):
    """More seeds of some curves (issue 44's image VD and L2) run without the figure's other methods, and the
    record's command names the methods, so that it remakes this folder and no more."""
    from vdtutorial.experiments.figures import figure_specs

    specs = figure_specs("fig4", seeds=(3, 4), obs_mode="rgbd", methods=("l2", "vd"))
    assert [(spec.method, spec.seed) for spec in specs] == [("vd", 3), ("vd", 4), ("l2", 3), ("l2", 4)]
    main(
        [
            "experiment",
            "fig4",
            "--seeds",
            "0",
            "--steps",
            "200",
            "--methods",
            "expert",
            "--workers",
            "1",
            "--out",
            str(tmp_path),
        ]
    )
    record = json.loads((tmp_path / "fig4.json").read_text())
    assert {run["method"] for run in record["runs"]} == {"expert"}
    assert "--methods expert" in record["command"]


def test_a_new_draw_of_the_data_runs_apart_from_the_shipped_one(tmp_path):
    """Issue 44's second data set: ``--demo-seed 1 --sigmas 0.05 0.25`` makes fig6's VD and L2 runs on those two
    data sets only, pre-trained on the demonstrations of seed 1. Their runs and checkpoints are named apart from the
    shipped seed 0's (which keep their names), and the record's command names all three options."""
    from vdtutorial.experiments.checkpoints import checkpoint_path
    from vdtutorial.experiments.figures import figure_specs
    from vdtutorial.experiments.results import experiment_command

    specs = figure_specs("fig6", seeds=(0,), demo_seed=1, sigmas=(0.05, 0.25))
    assert [(s.method, s.noise, s.demo_seed) for s in specs] == [
        ("vd", 0.05, 1),
        ("vd", 0.25, 1),
        ("l2", 0.05, 1),
        ("l2", 0.25, 1),
    ]
    assert specs[0].name == "vd_reach_n8000_sigma0.05_demos1_state_seed0"
    assert figure_specs("fig6", seeds=(0,), sigmas=(0.05,))[0].name == "vd_reach_n8000_sigma0.05_state_seed0"
    assert [s.samples for s in figure_specs("fig5", seeds=(0,), samples=(2000,))] == [2000, 2000]
    meta = {"task": "reach", "samples": 8000, "noise": 0.05}
    assert checkpoint_path({**meta, "seed": 0}, "vd", "state", 3).name == "reach_n8000_sigma0.05_vd_state_seed3.pt"
    assert (
        checkpoint_path({**meta, "seed": 1}, "vd", "state", 3).name == "reach_n8000_sigma0.05_demos1_vd_state_seed3.pt"
    )
    assert "--sigmas 0.05 0.25 --demo-seed 1" in experiment_command(
        "fig6", seeds=(0,), sigmas=("0.05", "0.25"), demo_seed=1
    )


# -- errors: one line, exit code 2, no traceback ----------------------------------------------------------
def _one_line_error(capsys, argv) -> str:
    try:
        code = main(argv)
    except SystemExit as exit_info:  # argparse refusals
        code = exit_info.code
    err = capsys.readouterr().err.replace("[quick mode: small budgets]\n", "")
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["demos", "--samples", "-5"], "--samples: expected a positive integer, got '-5'"),
        (["demos", "--samples", "0"], "expected a positive integer"),
        (["experiment", "fig5", "--methods", "none"], "fig5 has no method none: its methods are vd, l2"),
        (["experiment", "table1", "--methods", "vd"], "--methods is an option of the figures"),
        (["experiment", "table1", "--demo-seed", "1"], "--demo-seed is an option of the figures"),
        (
            ["experiment", "fig6", "--sigmas", "0.3"],
            "fig6 has no such data set: its data sets are 8000 demonstrations at Sigma 0.05",
        ),
        (["experiment", "fig5", "--samples", "1000"], "fig5 has no such data set"),
        (
            ["experiment", "fig6", "--demo-seed", "7"],
            "no demonstrations of seed 7 for 8000 samples at Sigma 0.05: make "
            "them with python -m vdtutorial demos --task reach --samples 8000 "
            "--noise 0.05 --seed 7 --out data/demos/reach_n8000_sigma0.05_seed7.npz",
        ),
        (["demos", "--noise", "-0.1"], "--noise: expected a finite number >= 0"),
        (["demos", "--noise", "nan"], "--noise: expected a finite number >= 0"),
        (["demos", "--task", "push"], "invalid choice: 'push'"),
        (["expert", "--episodes", "0"], "--episodes: expected a positive integer, got '0'"),
        (["expert", "--episodes", "many"], "--episodes: expected a positive integer, got 'many'"),
        (["experiment", "fig9"], "invalid choice: 'fig9'"),
        (["experiment", "fig4", "--steps", "0"], "--steps: expected a positive integer"),
        (["experiment", "fig4", "--workers", "-1"], "--workers: expected a positive integer"),
        (["experiment", "fig4", "--fvp-subsample", "1.5"], "--fvp-subsample: expected a number in (0, 1]"),
        (
            ["pretrain", "--reg", "mixup", "--demos", "x.npz"],
            "--reg mixup: not a pre-training method (they are vd, l2, vd_unpruned, dropout)",
        ),
        (["pretrain", "--reg", "none", "--demos", "x.npz"], "--reg none: not a pre-training method"),
        (
            ["experiment", "fig4", "--methods", "vd", "mixup"],
            "no method 'mixup': the methods are vd, l2, none, expert, vd_unpruned, dropout",
        ),
        (["bench", "gpu"], "invalid choice: 'gpu'"),
        (["bench", "env", "--profile"], "--profile is an option of bench finetune only"),
        (["train"], "invalid choice: 'train'"),
        (["rederive", "nowhere"], "nowhere is not an experiment folder"),
        (
            ["experiment", "table1", "--restart", "--state-dir", "x"],
            "table1 pre-trains only (no TRPO runs to resume): --state-dir, --restart are options of the figures",
        ),
        (
            ["experiment", "beyond", "--fvp-subsample", "0.1"],
            "beyond fine-tunes with the paper's TRPO settings: --fvp-subsample is an option of the figures",
        ),
        (["experiment", "beyond", "--obs", "rgbd"], "beyond runs in state mode only (--obs state)"),
    ],
)
def test_bad_arguments_give_one_line(argv, expected, capsys):
    assert expected in _one_line_error(capsys, argv)


def test_ctrl_c_gives_one_line_and_the_shell_code(monkeypatch, capsys):
    """Ctrl-C during an experiment: no traceback, exit code 130 (128 + SIGINT), and how to continue."""
    from vdtutorial import experiments

    def interrupted(**kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(experiments, "fig4", interrupted)
    assert main(["experiment", "fig4", "--seeds", "0"]) == 130
    err = capsys.readouterr().err.replace("[quick mode: small budgets]\n", "")
    assert (
        err.startswith("interrupted: ")
        and "rerun the same command (without --restart) to continue" in err
        and "Traceback" not in err
    )
    assert err.count("\n") == 1


def test_missing_and_corrupt_files_give_one_line_with_the_real_regenerate_command(tmp_path, capsys):
    missing = tmp_path / "grasp_n4000_sigma0.25_seed3.npz"
    err = _one_line_error(capsys, ["evaluate", "--demos", str(missing)])
    assert f"python -m vdtutorial demos --task grasp --samples 4000 --noise 0.25 --seed 3 --out {missing}" in err
    corrupt = tmp_path / "reach_n100_sigma0.5_seed0.npz"
    corrupt.write_bytes(b"not a zip archive")
    err = _one_line_error(capsys, ["pretrain", "--reg", "vd", "--demos", str(corrupt)])
    assert "is corrupt or not a demonstrations file" in err and "--samples 100 --noise 0.5 --seed 0" in err


def test_truncated_checkpoint_gives_one_line(tmp_path, capsys):
    name = "reach_n8000_sigma0.5_vd_state_seed0.pt"
    data = (data_dir() / "checkpoints" / name).read_bytes()
    (tmp_path / name).write_bytes(data[: len(data) // 2])
    err = _one_line_error(capsys, ["evaluate", "--checkpoints", str(tmp_path), "--episodes", "1"])
    assert "is corrupt or not a vdtutorial checkpoint" in err
    assert "python -m vdtutorial pretrain --reg vd" in err and "--seed 0 --obs state" in err


def test_shipped_files_are_not_replaced_without_force(tmp_path, capsys):
    shipped = data_dir() / "demos" / "reach_n8000_sigma0.5_seed0.npz"
    before = shipped.read_bytes()
    err = _one_line_error(capsys, ["demos", "--samples", "5", "--out", str(shipped)])
    assert "pass --force" in err and shipped.read_bytes() == before


# -- the help ---------------------------------------------------------------------------------------------
def _subparsers():
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, action.choices


def test_help_is_complete():
    parser, commands = _subparsers()
    assert "`" not in parser.format_help()
    assert all(word in parser.format_help() for word in ("demos", "pretrain", "experiment", "reproduce"))
    for name, sub in commands.items():
        assert "`" not in sub.format_help(), name
        for action in sub._actions:
            if not isinstance(action, argparse._HelpAction):
                assert action.help, f"{name} {action.option_strings or action.dest} has no help text"
    assert "finetune" in commands["bench"].format_help() and "trpo" in commands["bench"].format_help()
    epochs = next(a for a in commands["pretrain"]._actions if "--epochs" in a.option_strings)
    assert any(ch.isdigit() for ch in epochs.help) and "default_config" not in epochs.help


def test_no_pybullet_banner_on_help():
    result = subprocess.run([sys.executable, "-m", "vdtutorial", "--help"], capture_output=True, text=True, check=True)
    assert "build time" not in result.stdout + result.stderr
    assert result.stdout.startswith("usage: python -m vdtutorial")


# -- the README's examples leave data/ as shipped ---------------------------------------------------------
def _readme_examples() -> list[list[str]]:
    """The command lines of the README's "The command line" block, options in brackets dropped."""
    text = (REPO / "README.md").read_text()
    block = text.split("## The command line", 1)[1].split("```bash", 1)[1].split("```", 1)[0]
    commands = []
    for line in block.splitlines():
        line = re.sub(r"\[[^\]]*\]", "", line.split("#", 1)[0]).strip()
        if line.startswith("python -m vdtutorial "):
            commands.append(shlex.split(line)[3:])
    return commands


#: Budgets shrunk for a test (the commands' meaning is unchanged); bench and digits only measure.
SMALLER = {"--samples": "60", "--episodes": "1", "--steps": "200"}
EXTRA = {
    "pretrain": ["--epochs", "1"],
    "evaluate": ["--episodes", "1"],
    "experiment": ["--seeds", "0", "--workers", "1"],
    "reproduce": ["--workers", "1"],
}


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.skipif(not is_quick(), reason="runs every README example: quick mode keeps it to a minute")
def test_readme_examples_leave_data_untouched(tmp_path):
    examples = _readme_examples()
    assert {"demos", "pretrain", "evaluate", "experiment", "reproduce"} <= {e[0] for e in examples}
    before = _digest(data_dir())
    env = {**os.environ, "VDTUTORIAL_QUICK": "1", "VDTUTORIAL_RUNS": str(tmp_path / "runs"), "MPLBACKEND": "Agg"}
    for argv in examples:
        if argv[0] in ("digits", "bench", "notebooks"):  # notebooks writes outside runs/: tests/test_install_routes.py
            continue
        argv = [SMALLER.get(prev, arg) for prev, arg in zip([None] + argv, argv)] + EXTRA.get(argv[0], [])
        result = subprocess.run(
            [sys.executable, "-m", "vdtutorial", *argv], cwd=REPO, env=env, capture_output=True, text=True
        )
        assert result.returncode == 0, f"{argv}: {result.stderr[-2000:]}"
    assert _digest(data_dir()) == before
    written = {p.relative_to(tmp_path / "runs").parts[0] for p in (tmp_path / "runs").rglob("*") if p.is_file()}
    assert {"demos", "checkpoints"} <= written
