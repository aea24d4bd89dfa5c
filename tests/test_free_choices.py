"""Our free choices, each changed alone (vdtutorial.experiments.free_choices): the rows, their comparisons,
the likelihood-sigma equivalence the module relies on, and one small run end to end."""

import json
from pathlib import Path

import pytest
import torch

from vdtutorial.experiments import free_choices as fc
from vdtutorial.experiments import read_rows
from vdtutorial.experiments.effects import claim_effects
from vdtutorial.experiments.results import results_file
from vdtutorial.methods import METHOD_LABELS
from vdtutorial.settings import data_dir, is_quick
from conftest import require_locked

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only


def test_each_row_changes_one_value_of_one_method():
    for choice in fc.CHOICES:
        config, default = choice.config(), fc.default_config(choice.method)
        changed = {k for k in vars(config) if getattr(config, k) != getattr(default, k)}
        assert changed == set(choice.change), choice.name
        assert choice.label.startswith(METHOD_LABELS[choice.method])


def test_a_row_compares_its_changed_method_with_the_other_methods_default():
    claims = fc.claims(("l2_small", "kl_weak"))
    pairs = {(c.text.split("]")[0][1:], c.measure): (c.a, c.b) for c in claims}
    vd, l2 = METHOD_LABELS["vd"], METHOD_LABELS["l2"]
    small, weak = (next(c for c in fc.CHOICES if c.name == n) for n in ("l2_small", "kl_weak"))
    assert pairs[("default", "final")] == (vd, l2)
    assert pairs[("l2_small", "auc")] == (vd, small.label)
    assert pairs[("kl_weak", "final")] == (weak.label, l2)
    assert len(claims) == 6


def test_the_likelihood_sigma_is_the_regulariser_weight_in_disguise():
    """Cloning with the likelihood's sigma 0.1 and L2 coefficient c takes Adam's steps of sigma 0.3 and c / 9:
    the two losses differ by a constant factor (the row l2_small stands for both)."""
    torch.manual_seed(0)
    obs, actions = torch.randn(256, 5), torch.randn(256, 2)
    start = torch.nn.Sequential(torch.nn.Linear(5, 16), torch.nn.Tanh(), torch.nn.Linear(16, 2))

    def cloned(sigma: float, coefficient: float):
        net = torch.nn.Sequential(torch.nn.Linear(5, 16), torch.nn.Tanh(), torch.nn.Linear(16, 2))
        net.load_state_dict(start.state_dict())
        optimiser = torch.optim.Adam(net.parameters(), lr=1e-2)
        for _ in range(100):
            nll = -torch.distributions.Normal(net(obs), sigma).log_prob(actions).sum(-1).mean()
            loss = nll + coefficient * sum((p**2).sum() for n, p in net.named_parameters() if n.endswith("weight"))
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        return torch.cat([p.detach().reshape(-1) for p in net.parameters()])

    assert torch.allclose(cloned(0.1, 1e-2), cloned(0.3, 1e-2 / 9), rtol=1e-4, atol=1e-5)
    assert not torch.allclose(cloned(0.1, 1e-2), cloned(0.3, 1e-2), rtol=1e-4, atol=1e-5)


def test_unknown_rows_are_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="unknown free choice.*'l2_tiny'"):
        fc.free_choices(names=("l2_tiny",), out=tmp_path)


@pytest.mark.skipif(not is_quick(), reason="runs the pipeline: quick mode only")
def test_a_small_sweep_writes_its_table_and_resumes(tmp_path):
    out = tmp_path / "free_choices"
    record = fc.free_choices(names=("l2_small",), seeds=(0, 1), steps=400, out=out, workers=1, progress=False)
    assert [(r["row"], r["kind"]) for r in record["table"]] == [
        ("default", "final"),
        ("default", "auc"),
        ("l2_small", "final"),
        ("l2_small", "auc"),
    ]
    for row in record["table"]:
        assert row["low"] <= row["estimate"] <= row["high"]
        assert row["holm_verdict"] in ("confirmed", "contradicted", "not confirmed")
        assert ("--choices l2_small" in row["command"]) == (row["row"] == "l2_small")
    assert json.loads((out / "free_choices.json").read_text())["table"] == record["table"]
    assert sorted(p.parent.name for p in (out / "runs").rglob("*.pt")) == ["default"] * 4 + ["l2_small"] * 2
    # the changed row pre-trained into its own folder; the default row's L2 checkpoint is another one
    assert {p.parts[-3] for p in (out / "checkpoints").rglob("*.pt")} >= {"l2_small"}
    again = fc.free_choices(names=("l2_small",), seeds=(0, 1), steps=400, out=out, workers=1, progress=False)
    assert again["table"] == record["table"]


SHIPPED = data_dir() / "results" / "free_choices"


def test_the_shipped_table_is_rederived_from_its_rows_and_is_on_the_results_page():
    require_locked("scipy")
    record = json.loads((SHIPPED / "free_choices.json").read_text())
    assert not record["quick"] and record["steps"] == 100_000 and len(record["seeds"]) >= 3
    names = [c["name"] for c in record["choices"]]
    assert names == list(fc.CHOICE_NAMES)  # every row ran
    rows = read_rows(results_file(SHIPPED, "free_choices"))
    effects = claim_effects("free_choices", rows, "successes", record["window"], claims=fc.claims(names))
    derived = fc.table(effects, names, lambda row: "")
    assert [{k: v for k, v in r.items() if k != "command"} for r in derived] == [
        {k: v for k, v in r.items() if k != "command"} for r in record["table"]
    ]
    # every measure's claims too, the secondary ones one Holm family (what rederive re-writes)
    assert json.loads(json.dumps(effects, default=str)) == record["claims"]
    assert {c["family"] for c in record["claims"]} == {"primary", "secondary"}
    page = (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text()
    assert fc.markdown_table(record) in page
