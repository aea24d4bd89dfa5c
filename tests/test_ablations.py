"""The two ablations of VD in the method table: VD without pruning (VD's own network and start sigma, every weight of
mu kept in RL) and binary dropout at a rate named in the method (Bernoulli masks on mu's weights while cloning, none
at evaluation or in RL); and the command that measures the rate matched to VD."""

from __future__ import annotations

import json
from pathlib import Path
import pytest
import torch
from torch import nn

from vdtutorial.cli import main
from vdtutorial.envs import ENV_IDS
from vdtutorial.dropconnect import DropConnect, dropconnect
from vdtutorial.methods import METHOD_LABELS, METHODS, method
from vdtutorial.runner import read_rows
from vdtutorial.settings import data_dir, is_quick
from vdtutorial.vd import svdo_layers

RATE = 0.3
ROOT = Path(__file__).resolve().parents[1]


def test_the_dropout_rate_is_part_of_the_name():
    entry = method("dropout@0.30")
    assert (entry.name, entry.rate, entry.spread_from, entry.variational) == ("dropout@0.3", 0.3, "vd", False)
    assert entry == method("dropout@0.3") and "p=0.3" in entry.label
    for name, words in (
        ("dropout", "takes its dropout rate in its name"),
        ("dropout@1", "a number in (0, 1)"),
        ("dropout@x", "a number in (0, 1)"),
        ("vd@0.3", "takes no @parameter"),
    ):
        with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
            method(name)
    unpruned = method("vd_unpruned")
    assert (unpruned.variational, unpruned.prunes, unpruned.network_of) == (True, False, "vd")
    assert {"vd_unpruned", "dropout"} <= set(METHODS)
    labels = dict(METHOD_LABELS)  # every name of the table has a label, a family's bare name too
    assert labels["dropout"] == "binary dropout" and METHOD_LABELS["dropout@0.2"] == "binary dropout, p=0.2"


def test_dropconnect_masks_weights_in_training_only_and_leaves_the_plain_network():
    """Inside the block: the same parameters under the same names; in training mode two passes differ, the mean over
    many examples is the plain output (the masks are rescaled by 1 / (1 - p)) and about p of the weights are dropped
    per example; in eval mode the output is the plain network's exactly. After the block the layers are plain."""
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(4, 6), nn.Tanh(), nn.Sequential(nn.Linear(6, 2)))
    keys, params = list(net.state_dict()), [id(p) for p in net.parameters()]
    x = torch.randn(1, 4).expand(20000, 4)
    plain = net(x[:1]).detach()
    with dropconnect(net, RATE):
        assert isinstance(net[0], DropConnect) and isinstance(net[2][0], DropConnect)
        assert list(net.state_dict()) == keys and [id(p) for p in net.parameters()] == params
        net.train()
        first = net[0](x).detach()
        assert not torch.equal(net(x[:8]), net(x[:8]))
        # the first layer's output per example: linear in the mask, so its mean over examples is the plain output
        assert torch.allclose(first.mean(0), net[0].plain(x[:1])[0].detach(), atol=0.03)
        assert first.std(0).min() > 0.05
        net.eval()
        assert torch.equal(net(x[:1]).detach(), plain)
    assert type(net[0]) is nn.Linear and type(net[2][0]) is nn.Linear
    assert list(net.state_dict()) == keys and torch.equal(net(x[:1]).detach(), plain)
    with pytest.raises(ValueError, match="in \\[0, 1\\)"):
        with dropconnect(net, 1.0):
            pass


def test_dropout_cloning_goes_through_the_masks():
    """Cloning with ``dropout@P`` passes every minibatch through masked weights (a spy on the layers' forward counts
    the training-mode passes with masks) and gives another network than L2 alone with the same seed and data, a plain
    one: after cloning no layer of mu is a DropConnect."""
    from vdtutorial.demos import generate_demos
    from vdtutorial.pretrain import PretrainConfig, pretrain

    demos = generate_demos("reach", 300, 0.1, 0, progress=False)
    masked = []
    original = DropConnect.forward

    def spy(self, x):
        masked.append(self.training)
        return original(self, x)

    DropConnect.forward = spy
    try:
        dropout, _ = pretrain(demos, PretrainConfig(reg=f"dropout@{RATE}", epochs=2), progress=False)
    finally:
        DropConnect.forward = original
    l2, _ = pretrain(demos, PretrainConfig(reg="l2", epochs=2), progress=False)
    assert masked.count(True) > 0 and masked.count(False) > 0  # training batches and the held-out evaluation
    assert not any(isinstance(m, DropConnect) for m in dropout.mu.modules())
    assert list(dropout.state_dict()) == list(l2.state_dict())
    assert not torch.equal(dropout.mu.head[0].weight, l2.mu.head[0].weight)


@pytest.mark.skipif(not is_quick(), reason="pre-trains and fine-tunes three policies: quick mode keeps it to seconds")
def test_the_ablations_run_in_fig4_through_the_command_line(tmp_path, capsys):
    """``experiment fig4 --methods vd vd_unpruned dropout@P``: each runs; VD without pruning starts from VD's own
    checkpoint (no checkpoint of its own), with every weight of mu kept and frozen, where VD drops some; binary
    dropout's network is plain and its checkpoints are named by its rate."""
    from vdtutorial.experiments.checkpoints import load_checkpoint
    from vdtutorial.experiments.pipeline import finetune_policy, load_demos
    from vdtutorial.rollout import make_vec_env

    out = tmp_path / "fig4"
    dropout = f"dropout@{RATE}"
    argv = ["experiment", "fig4", "--methods", "vd", "vd_unpruned", dropout, "--seeds", "0", "--steps", "400"]
    assert main([*argv, "--workers", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "VD without pruning: final" in printed and f"binary dropout, p={RATE}: final" in printed
    record = json.loads((out / "fig4.json").read_text())
    assert [run["method"] for run in record["runs"]] == ["vd", "vd_unpruned", dropout]
    assert f"--methods vd vd_unpruned {dropout}" in record["command"]
    rows = read_rows(out / "fig4.csv.gz")
    assert {row["method"] for row in rows} == {"vd", "vd_unpruned", dropout}
    names = {path.name for path in (out / "checkpoints").glob("*.pt")}
    assert not any("vd_unpruned" in name for name in names)
    assert f"reach_n8000_sigma0.5_{dropout}_state_seed0_initsigma-spread.pt" in names
    assert "reach_n8000_sigma0.5_vd_state_seed0_initsigma-spread.pt" in names

    demos = load_demos("reach")
    env = make_vec_env(ENV_IDS["reach"], 2)
    try:
        policies = {
            name: finetune_policy(name, env, demos, checkpoints_root=out) for name in ("vd", "vd_unpruned", dropout)
        }
    finally:
        env.close()
    vd, unpruned = policies["vd"], policies["vd_unpruned"]
    cloned = load_checkpoint(out / "checkpoints" / "reach_n8000_sigma0.5_vd_state_seed0_initsigma-spread.pt")
    for layer, theta in zip(svdo_layers(unpruned.mu), svdo_layers(cloned.mu)):
        assert bool(layer.pruned) and bool(layer.mask.all()) and not layer.log_sigma2.requires_grad
        assert torch.equal(layer.weight, theta.weight)  # VD's cloned network, nothing dropped
    assert sum(int((~layer.mask).sum()) for layer in svdo_layers(vd.mu)) > 0
    for ours, vds in zip(svdo_layers(unpruned.sigma), svdo_layers(vd.sigma)):
        assert torch.equal(ours.mask, vds.mask) and torch.equal(ours.weight, vds.weight)  # VD's start sigma
    assert not svdo_layers(policies[dropout])
    assert all(type(m) is not DropConnect for m in policies[dropout].modules())


def test_pretrain_sends_vd_without_pruning_to_vds_network(capsys):
    demos = data_dir() / "demos" / "reach_n2000_sigma0.5_seed0.npz"
    assert main(["pretrain", "--reg", "vd_unpruned", "--demos", str(demos)]) == 2
    assert "starts from the vd network: pretrain --reg vd" in capsys.readouterr().err
    assert main(["pretrain", "--reg", "dropout", "--demos", str(demos)]) == 2
    assert "takes its dropout rate in its name" in capsys.readouterr().err


def test_the_matched_rate_is_the_mean_of_alpha_over_one_plus_alpha_of_the_kept_weights(tmp_path, capsys):
    """Known log alphas in a VD checkpoint give the known rate: kept weights at log alpha 0 (p = 1/2) and log 3
    (p = 3/4), pruned ones (log alpha 5) left out; and two copies of it average to the same."""
    from vdtutorial.experiments.checkpoints import load_checkpoint, save_checkpoint

    shipped = data_dir() / "checkpoints" / "reach_n2000_sigma0.5_vd_state_seed0.pt"
    policy = load_checkpoint(shipped)
    with torch.no_grad():
        layers = svdo_layers(policy.mu)
        for k, layer in enumerate(layers):
            log_alpha = torch.full_like(layer.weight, 0.0 if k % 2 == 0 else float(torch.log(torch.tensor(3.0))))
            log_alpha.view(-1)[::2] = 5.0  # pruned
            layer.log_sigma2.copy_(log_alpha + torch.log(layer.weight**2 + 1e-8))
    kept = [(layer.weight.numel() + 1) // 2 for layer in layers]
    half = sum(n for k, n in enumerate(kept) if k % 2 == 1)
    expected = (0.5 * (sum(kept) - half) + 0.75 * half) / sum(kept)
    paths = [save_checkpoint(policy, tmp_path / f"copy{k}.pt") for k in range(2)]
    assert main(["dropout-rate", *map(str, paths)]) == 0
    printed = capsys.readouterr().out
    assert f"p = {expected:.4f}" in printed.splitlines()[0]
    assert f"mean over 2 checkpoints p = {expected:.4f}" in printed
    other = data_dir() / "checkpoints" / "reach_n4000_sigma0.5_vd_state_seed0.pt"
    assert main(["dropout-rate", str(paths[0]), str(other)]) == 2
    assert "2 data sets" in capsys.readouterr().err


def test_the_planned_commands_make_forty_runs_with_two_workers(monkeypatch):
    """The plan's commands (docs/plan-ablations-and-image-fig5.md) build their runs without running them: the shipped
    table names both ablations, so two worker processes know them (a method registered in one process would be
    refused), and each command is the 4 methods times 10 seeds on its one data set."""
    import vdtutorial.experiments.figures as figures

    seen = {}

    def capture(name, specs, title, out, workers, command=None, **kwargs):
        seen.update(specs=specs, command=command)
        raise SystemExit(0)

    monkeypatch.setattr(figures, "run_experiment", capture)
    plan = (ROOT / "docs" / "plan-ablations-and-image-fig5.md").read_text()
    for figure, option, data in (("fig6", "--sigmas 0.25", (8000, 0.25)), ("fig5", "--samples 2000", (2000, 0.5))):
        start = plan.index(f"python -m vdtutorial experiment {figure} {option} --methods vd l2 vd_unpruned dropout@")
        argv = plan[start : plan.index("/state", start) + len("/state")].replace("\\\n", " ").split()[3:]
        with pytest.raises(SystemExit):
            main(argv)
        assert "--workers 2" in seen["command"] and len(seen["specs"]) == 40
        assert {(s.samples, s.noise) for s in seen["specs"]} == {data}
        methods = {s.method for s in seen["specs"]}
        assert methods - {"vd", "l2", "vd_unpruned"} == {next(m for m in argv if m.startswith("dropout@"))}
