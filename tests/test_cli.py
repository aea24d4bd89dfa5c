"""The command line: each subcommand parses, and the cheap ones run end to end."""
import json

import pytest

from vdtutorial.__main__ import build_parser, main
from vdtutorial.demos import Demos
from vdtutorial.settings import QUICK


@pytest.mark.parametrize("command", ["demos", "expert", "pretrain", "evaluate", "digits", "bench", "experiment", "reproduce"])
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage" in capsys.readouterr().out


def test_demos_command_writes_the_file_it_prints(tmp_path, capsys):
    out = tmp_path / "d.npz"
    main(["demos", "--task", "reach", "--samples", "30", "--noise", "0.1", "--seed", "4", "--out", str(out), "--no-progress"])
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


@pytest.mark.skipif(not QUICK, reason="the full-size main job takes minutes; CI runs it in quick mode")
def test_reproduce_runs_the_whole_pipeline(tmp_path, capsys):
    main(["reproduce", "--quick", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    for label in ("VD: final", "L2: final", "no pre-training: final", f"wrote {tmp_path}"):
        assert label in printed
    assert (tmp_path / "reproduce_quick.png").exists() and (tmp_path / "sparsity.txt").exists()
    assert len(list((tmp_path / "runs").glob("*.csv"))) == 9  # 3 methods x 3 seeds


@pytest.mark.skipif(not QUICK, reason="pre-trains VD and L2 policies: quick mode keeps it to seconds")
def test_experiment_fvp_subsample_reaches_the_runs_and_the_record(tmp_path, capsys):
    main(["experiment", "fig4", "--seeds", "0", "--steps", "200", "--fvp-subsample", "0.5", "--workers", "1",
          "--out", str(tmp_path)])
    assert "VD: final" in capsys.readouterr().out
    record = json.loads((tmp_path / "fig4.json").read_text())
    assert record["trpo_config"]["fvp_subsample"] == 0.5
    assert "--fvp-subsample 0.5" in record["command"]
