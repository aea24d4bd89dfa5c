"""The table of methods: adding one is one entry (the paper's four, then two ablations of VD:
tests/test_ablations.py). A method defined here, in the test file (L1 on mu's weights), registered and nothing else,
runs through the command line's Fig. 4 beside VD; and no code outside the table decides anything by a method's
name."""

from __future__ import annotations

import ast
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import vdtutorial
import vdtutorial.methods as methods
from vdtutorial.cli import main
from vdtutorial.methods import CloningStep, Method, method, register
from vdtutorial.runner import read_rows
from vdtutorial.settings import is_quick

PACKAGE = Path(vdtutorial.__file__).parent
#: The names of the entries that pre-train or stand for no pre-training, which only the table may compare to.
NAMES = {"vd", "l2", "none"}


@dataclass(frozen=True)
class L1(Method):
    """L1 on the weights of mu: ``coefficient * sum |W|`` (biases excluded)."""

    coefficient: float = 1e-3

    def penalty(self, mu: torch.nn.Module, at: CloningStep) -> torch.Tensor:
        return self.coefficient * sum(p.abs().sum() for name, p in mu.named_parameters() if name.endswith("weight"))


@pytest.fixture
def table(monkeypatch):
    """The table as shipped, restored after the test whatever it registers."""
    monkeypatch.setattr(methods, "METHODS", dict(methods.METHODS))
    return methods


def test_the_shipped_entries_are_the_papers_and_cannot_be_replaced(table):
    assert list(table.METHODS) == ["vd", "l2", "none", "expert", "vd_unpruned", "dropout"]
    vd, l2 = method("vd"), method("l2")
    assert (vd.variational, vd.prunes, vd.spread_from) == (True, True, None)
    assert (l2.variational, l2.prunes, l2.spread_from) == (False, False, "vd")
    assert table.pretraining_methods() == ("vd", "l2", "vd_unpruned", "dropout")
    with pytest.raises(ValueError, match="shipped method"):
        register(L1("l2", "my L2", "tab:purple"))
    with pytest.raises(ValueError, match="no method 'l1'"):
        method("l1")


def test_a_registered_penalty_is_what_cloning_adds_to_the_likelihood(table):
    """The L1 entry's term is the coefficient times the weights' absolute sum, and cloning with it shrinks that sum
    below cloning with no term at all (the same seed, data and epochs)."""
    from vdtutorial.demos import generate_demos
    from vdtutorial.pretrain import PretrainConfig, pretrain

    register(L1("l1", "L1", "tab:purple", coefficient=0.05))
    register(Method("plain", "no penalty", "tab:green"))
    mu = torch.nn.Sequential(torch.nn.Linear(2, 3))
    expected = 0.05 * mu[0].weight.abs().sum()
    assert torch.isclose(method("l1").penalty(mu, CloningStep(0, 1, 1, None)), expected)
    demos = generate_demos("reach", 300, 0.1, 0, progress=False)

    def weight_l1(reg):
        policy, history = pretrain(demos, PretrainConfig(reg=reg, epochs=3), progress=False)
        assert "weights_pruned" not in history[-1]
        return sum(p.abs().sum().item() for name, p in policy.mu.named_parameters() if name.endswith("weight"))

    assert weight_l1("l1") < weight_l1("plain")


def _pixels_near(path: Path, colour: str, tolerance: float = 40.0) -> int:
    from matplotlib.colors import to_rgb

    image = np.asarray(Image.open(path).convert("RGB"), dtype=float)
    return int((np.linalg.norm(image - 255 * np.array(to_rgb(colour)), axis=-1) < tolerance).sum())


@pytest.mark.skipif(not is_quick(), reason="pre-trains and fine-tunes three policies: quick mode keeps it to seconds")
def test_a_method_defined_here_runs_in_fig4_through_the_command_line(table, tmp_path, capsys):
    """``experiment fig4 --methods vd l1``: L1's runs are in the record with their rows, its curve in the plot, its
    start sigma follows VD's network (its entry's default), and no file of the package was edited for it."""
    register(L1("l1", "L1", "tab:purple"))
    out = tmp_path / "fig4"
    assert (
        main(
            [
                "experiment",
                "fig4",
                "--methods",
                "vd",
                "l1",
                "--seeds",
                "0",
                "--steps",
                "400",
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "L1: final" in capsys.readouterr().out
    record = json.loads((out / "fig4.json").read_text())
    assert [(run["method"], run["label"]) for run in record["runs"]] == [("vd", "VD"), ("l1", "L1")]
    assert "--methods vd l1" in record["command"]
    rows = read_rows(out / "fig4.csv.gz")
    assert {row["method"] for row in rows} == {"vd", "l1"}
    assert sum(row["method"] == "l1" for row in rows) == 2  # 400 steps: two iterations of 200
    pngs = sorted(out.glob("*.png"))
    assert pngs and _pixels_near(pngs[0], "tab:purple") > 50 and _pixels_near(pngs[0], "tab:blue") > 50
    checkpoints = {path.name for path in (out / "checkpoints").glob("*_l1_state_seed0*.pt")}
    assert {
        "reach_n8000_sigma0.5_l1_state_seed0.pt",
        "reach_n8000_sigma0.5_l1_state_seed0_initsigma-spread.pt",
    } <= checkpoints


def test_an_unknown_method_is_a_one_line_error(capsys):
    assert main(["experiment", "fig4", "--methods", "vd", "l3", "--seeds", "0"]) == 2
    assert "no method 'l3'" in capsys.readouterr().err


def test_a_registered_method_asks_for_one_worker(table, tmp_path, capsys):
    """Spawned workers start from the shipped table: a method registered here would be unknown there."""
    register(L1("l1", "L1", "tab:purple"))
    assert (
        main(["experiment", "fig4", "--methods", "l1", "--seeds", "0", "--workers", "2", "--out", str(tmp_path)]) == 2
    )
    assert "l1: registered in this process only" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def _compares_a_name(node: ast.AST) -> bool:
    """``x == "vd"``, ``x != "none"``, ``x in ("vd", "l2")``: a comparison with a method's name."""
    if not isinstance(node, ast.Compare):
        return False
    sides = [node.left, *node.comparators]
    for side in sides:
        if isinstance(side, ast.Constant) and side.value in NAMES:
            return True
        if isinstance(side, (ast.Tuple, ast.Set, ast.List)) and any(
            isinstance(e, ast.Constant) and e.value in NAMES for e in side.elts
        ):
            return True
    return False


def test_no_code_outside_the_table_compares_a_method_name():
    found = [
        f"{path.relative_to(PACKAGE)}:{node.lineno}"
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "methods.py" or path.parent != PACKAGE
        for node in ast.walk(ast.parse(path.read_text()))
        if _compares_a_name(node)
    ]
    assert not found
    assert _compares_a_name(ast.parse('reg == "vd"').body[0].value)
    assert _compares_a_name(ast.parse('m in ("vd", "l2")').body[0].value)
