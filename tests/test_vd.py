"""Tests of vdtutorial.vd: the KL approximation, local reparameterisation, masks, pruning, compaction,
sparsity reports and the digits validation (quick budget)."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from scipy import integrate, stats
from torch import nn

from vdtutorial import vd
from vdtutorial.analysis.compact import compact
from vdtutorial.analysis.sparsity import sparsity_report, weight_layers
from vdtutorial.experiments.digits import digits_validation


def true_neg_kl_up_to_constant(log_alpha: float) -> float:
    """-KL(q || log-uniform) + C = 0.5 log alpha - E log|1 + sqrt(alpha) eps|. Writing
    1 + sqrt(alpha) eps = sqrt(alpha) (eps + c) with c = alpha^-1/2, the log alpha terms cancel and
    -KL + C = -E log|eps + c| = -int log|u| N(u; c, 1) du, integrated by adaptive quadrature on
    c +- 12 (the Gaussian tail beyond is < 1e-30), split at the integrable singularity u = 0."""
    c = math.exp(-log_alpha / 2)
    integrand = lambda u: math.log(abs(u)) * stats.norm.pdf(u - c)  # noqa: E731
    pieces = [(c - 12, 0.0), (0.0, c + 12)] if c < 12 else [(c - 12, c + 12)]
    return -sum(integrate.quad(integrand, a, b, limit=200)[0] for a, b in pieces)


def test_kl_approx_matches_quadrature_up_to_constant():
    log_alphas = np.linspace(vd.LOG_ALPHA_MIN, vd.LOG_ALPHA_MAX, 65)
    exact = np.array([true_neg_kl_up_to_constant(a) for a in log_alphas])
    approx = -vd.kl_approx(torch.tensor(log_alphas)).numpy()
    offset = approx - exact
    # Molchanov et al.'s fit is accurate to about 0.01 nats per weight; here the worst is 0.0073.
    assert np.abs(offset - offset.mean()).max() < 0.01
    # The approximation tends to 0 for alpha -> infinity while -E log|eps| = (gamma + log 2) / 2, which is
    # where k1 comes from: the constant is about -k1.
    assert offset.mean() == pytest.approx(-(np.euler_gamma + math.log(2)) / 2, abs=0.01)


def test_kl_approx_is_positive_and_decreasing():
    kl = vd.kl_approx(torch.linspace(-8, 8, 101))
    assert (kl > 0).all() and (kl.diff() < 0).all()


def test_gradients_finite_at_clip_edges():
    layer = vd.LinearSVDO(4, 1)
    with torch.no_grad():
        layer.weight.copy_(torch.tensor([[1.0, 1.0, 0.0, 1e-3]]))
        # log alpha exactly at -8 and 8, then beyond both edges; theta = 0 exercises log(theta^2 + eps).
        layer.log_sigma2.copy_(torch.tensor([[-8.0, 8.0, 5.0, -30.0]]))
    layer.kl().backward()
    assert torch.isfinite(layer.weight.grad).all() and torch.isfinite(layer.log_sigma2.grad).all()
    edges = torch.tensor([vd.LOG_ALPHA_MIN, vd.LOG_ALPHA_MAX], requires_grad=True)
    vd.kl_approx(edges).sum().backward()
    assert torch.isfinite(edges.grad).all() and (edges.grad < 0).all()


def _random_svdo(layer: vd.SVDOLayer, low: float, high: float) -> vd.SVDOLayer:
    with torch.no_grad():
        layer.log_sigma2.uniform_(low, high)
        layer.bias.uniform_(-1, 1)
    return layer


def _assert_moments(samples: torch.Tensor, mean: torch.Tensor, var: torch.Tensor) -> None:
    """Sample mean within 5 standard errors; sample variance within 5 standard errors of a Gaussian's
    variance estimate (relative sd sqrt(2 / n))."""
    n = samples.shape[0]
    assert ((samples.mean(0) - mean).abs() <= 5 * (var / n).sqrt() + 1e-6).all()
    assert ((samples.var(0) / var - 1).abs() <= 5 * math.sqrt(2 / n)).all()


def test_local_reparameterisation_linear_moments():
    torch.manual_seed(0)
    layer = _random_svdo(vd.LinearSVDO(5, 3), -4.0, 0.0).train()
    x = torch.randn(1, 5)
    with torch.no_grad():
        samples = layer(x.expand(40000, 5))
    # Weights w ~ N(theta, sigma^2) independent (eq. 4): output mean x theta^T + b, variance x^2 sigma^2^T.
    _assert_moments(samples, (x @ layer.weight.T + layer.bias)[0], (x**2 @ layer.log_sigma2.exp().T)[0])


def test_local_reparameterisation_conv_moments():
    torch.manual_seed(1)
    layer = _random_svdo(vd.Conv2dSVDO(2, 3, 3, padding=1), -4.0, 0.0).train()
    x = torch.randn(1, 2, 5, 5)
    with torch.no_grad():
        samples = layer(x.expand(20000, 2, 5, 5)).reshape(20000, 3, 25)
    # Independent check through explicit patches: each output is a dot product with one 2 x 3 x 3 patch.
    patches = F.unfold(x, 3, padding=1)[0]  # (18, 25)
    theta, sigma2 = layer.weight.reshape(3, 18), layer.log_sigma2.exp().reshape(3, 18)
    _assert_moments(samples, theta @ patches + layer.bias[:, None], sigma2 @ patches**2)


def test_eval_mask_zeroes_exactly_the_high_log_alpha_weights():
    torch.manual_seed(2)
    layer = _random_svdo(vd.LinearSVDO(6, 4), -12.0, 6.0).eval()
    log_alpha = torch.clamp(layer.log_sigma2 - torch.log(layer.weight**2 + 1e-8), -8, 8)
    dropped = log_alpha > 3
    assert 0 < dropped.sum() < dropped.numel()
    assert torch.equal(~layer.keep_mask(), dropped)
    x = torch.randn(7, 6)
    with torch.no_grad():
        expected = F.linear(x, torch.where(dropped, 0.0, layer.weight), layer.bias)
        assert torch.equal(layer(x), expected)
        assert torch.equal(layer(x), layer(x))  # deterministic


def test_layers_are_drop_in_replacements_for_torch_layers():
    torch.manual_seed(5)
    for svdo, plain, x in [
        (vd.LinearSVDO(5, 3), nn.Linear(5, 3), torch.randn(2, 5)),
        (vd.Conv2dSVDO(2, 3, 3, stride=2, padding=1), nn.Conv2d(2, 3, 3, stride=2, padding=1), torch.randn(2, 2, 7, 7)),
    ]:
        with torch.no_grad():
            svdo.weight.copy_(torch.where(svdo.weight.abs() < 0.01, 0.1, svdo.weight))  # none pruned at birth
            plain.weight.copy_(svdo.weight)
            plain.bias.copy_(svdo.bias)
            assert torch.allclose(svdo.eval()(x), plain(x), atol=1e-6)
            assert svdo.double()(x.double()).dtype == torch.float64  # Module.to / .double still work


def _pruned_mlp() -> nn.Sequential:
    torch.manual_seed(3)
    model = nn.Sequential(vd.LinearSVDO(6, 5), nn.Tanh(), vd.LinearSVDO(5, 2))
    for layer in vd.svdo_layers(model):
        _random_svdo(layer, -12.0, 6.0)
    return vd.prune_model(model)


def test_prune_keeps_pruned_weights_at_zero_during_fine_tuning():
    model = _pruned_mlp().train()
    layers = vd.svdo_layers(model)
    masks = [layer.mask.clone() for layer in layers]
    before = [layer.weight.detach().clone() for layer in layers]
    assert all(0 < (~m).sum() < m.numel() for m in masks)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=0.1)
    x, y = torch.randn(16, 6), torch.randn(16, 2)
    for _ in range(3):
        assert torch.equal(model(x), model(x))  # deterministic even in train mode
        optimiser.zero_grad()
        F.mse_loss(model(x), y).backward()
        for layer, mask in zip(layers, masks):
            assert (layer.weight.grad[~mask] == 0).all()
            assert layer.log_sigma2.grad is None and not layer.log_sigma2.requires_grad
        optimiser.step()
    for layer, mask, old in zip(layers, masks, before):
        assert (layer.weight[~mask] == 0).all()
        assert not torch.equal(layer.weight[mask], old[mask])  # the kept weights do train
        assert torch.equal(layer.mask, mask)


def test_pruned_state_survives_state_dict_round_trip():
    model = _pruned_mlp()
    fresh = nn.Sequential(vd.LinearSVDO(6, 5), nn.Tanh(), vd.LinearSVDO(5, 2))
    fresh.load_state_dict(model.state_dict())
    x = torch.randn(4, 6)
    assert torch.equal(fresh.train()(x), model.eval()(x))
    assert all(layer.pruned and not layer.log_sigma2.requires_grad for layer in vd.svdo_layers(fresh))


@torch.no_grad()
def test_model_kl_sums_layers_and_is_zero_for_plain_networks():
    model = _pruned_mlp()
    assert vd.model_kl(model).item() == pytest.approx(sum(layer.kl().item() for layer in vd.svdo_layers(model)))
    assert vd.model_kl(nn.Sequential(nn.Linear(3, 2))).item() == 0.0


def _set_pruned(layer: vd.SVDOLayer, index) -> None:
    """Give the weights at ``index`` log sigma^2 = 10, i.e. log alpha > 3 (as long as |theta| > e^-3.5)."""
    with torch.no_grad():
        layer.weight[index] = torch.where(layer.weight[index] >= 0, 0.5, -0.5)
        layer.log_sigma2[index] = 10.0


def _prune_at_random_keeping_units(layer: vd.SVDOLayer, fraction: float) -> None:
    """Prune about ``fraction`` of the (output, input) connections, but keep two connections in every row
    and every column, so that no unit dies by accident (a later single-row or single-column prune can
    remove only one of the two)."""
    pruned = torch.rand(layer.weight.shape[:2]) < fraction
    rows, cols = pruned.shape
    for k in range(max(rows, cols)):
        for shift in (0, 1):
            pruned[k % rows, (k + shift) % cols] = pruned[(k + shift) % rows, k % cols] = False
    pruned = pruned.reshape(rows, cols, *[1] * (layer.weight.dim() - 2)).expand_as(layer.weight)
    with torch.no_grad():
        layer.bias.uniform_(-1, 1)
        layer.weight.copy_(torch.where(layer.weight.abs() < 0.01, 0.1, layer.weight))  # none pruned at birth
        layer.log_sigma2.copy_(torch.where(pruned, 10.0, -10.0))


def test_compact_conv_stack_gives_identical_outputs_with_fewer_parameters():
    torch.manual_seed(4)
    c1, c2, c3 = vd.Conv2dSVDO(3, 6, 3), vd.Conv2dSVDO(6, 5, 3, padding=1), vd.Conv2dSVDO(5, 4, 3, stride=2)
    fc1, fc2 = vd.LinearSVDO(4 * 4 * 4, 7), vd.LinearSVDO(7, 3)
    model = nn.Sequential(c1, nn.ReLU(), c2, nn.Tanh(), c3, nn.ReLU(), nn.Flatten(), fc1, nn.Tanh(), fc2)
    for layer in vd.svdo_layers(model):
        _prune_at_random_keeping_units(layer, 0.3)
    _set_pruned(c1, (1,))  # c1 channel 1 dead-in, but c2 pads: kept (not foldable)
    _set_pruned(c2, (slice(None), 4))  # c1 channel 4 dead-out: removed
    _set_pruned(c2, (2,))  # c2 channel 2 dead-in, c3 has no padding: folded, removed
    _set_pruned(fc1, (slice(None), slice(3 * 16, 4 * 16)))  # c3 channel 3 dead-out through Flatten
    _set_pruned(fc1, (5,))  # fc1 unit 5 dead-in: folded into fc2's bias
    model.eval()
    small = compact(model)
    assert all(type(m) in (nn.Conv2d, nn.Linear) for m in weight_layers(small))
    assert [m.weight.shape[0] for m in weight_layers(small)] == [5, 4, 3, 6, 3]
    assert sum(p.numel() for p in small.parameters()) < sum(
        m.weight.numel() + m.bias.numel() for m in weight_layers(model)
    )
    x = torch.randn(8, 3, 12, 12)
    with torch.no_grad():
        assert torch.allclose(small(x), model(x), atol=1e-5)
    report = sparsity_report(model)
    assert [layer.dead for layer in report.layers] == [2, 1, 1, 1, 0]  # c1's unfoldable channel 1 counts as pruned


def test_sparsity_report_on_hand_built_network():
    l1, l2 = vd.LinearSVDO(4, 3), vd.LinearSVDO(3, 2)
    with torch.no_grad():
        for layer in (l1, l2):
            layer.weight.fill_(1.0)  # log theta^2 = 0, so log alpha = log sigma^2 (clamped)
    _set_pruned(l1, (0,))  # unit 0: all 4 incoming weights pruned -> dead-in
    _set_pruned(l1, (1, 2))  # one more pruned weight: 5 of 12
    _set_pruned(l2, (slice(None), 2))  # unit 2: both outgoing weights pruned -> dead-out
    _set_pruned(l2, (1, 0))  # unit 0 keeps one outgoing weight: 3 of 6 pruned
    report = sparsity_report(nn.Sequential(l1, nn.ReLU(), l2))
    first, last = report.layers
    assert (first.weights, first.pruned_weights, first.hidden_units) == (12, 5, 3)
    assert (first.dead_in, first.dead_out, first.dead) == (1, 1, 2)
    assert (last.weights, last.pruned_weights, last.hidden_units, last.dead) == (6, 3, 0, 0)
    assert report.weight_fraction == pytest.approx(8 / 18)
    assert report.compression == pytest.approx(18 / 10)
    fractions = (report.neuron_fraction, report.neuron_fraction_in, report.neuron_fraction_out)
    assert fractions == pytest.approx((2 / 3, 1 / 3, 1 / 3))
    assert "compression x1.8" in str(report)


def test_sparsity_report_needs_the_wiring():
    class Unknown(nn.Module):
        def __init__(self):
            super().__init__()
            self.layer = vd.LinearSVDO(2, 2)

    with pytest.raises(TypeError, match="weight_edges"):
        sparsity_report(Unknown())


def test_digits_validation_quick():
    result = digits_validation(seed=0, epochs=30)
    assert result.dense_accuracy > 0.95
    assert result.vd_accuracy > 0.85
    assert result.fraction_pruned > 0.5
    assert result.fraction_pruned == result.report.weight_fraction


def test_pruned_fraction_is_the_reports_weight_fraction_exactly():
    """Pre-training logs vd.pruned_fraction each epoch (the core cannot import the analysis); the shipped
    checkpoints' histories were written with sparsity_report(mu).weight_fraction: the same float."""
    from vdtutorial.demos import Demos, demo_path
    from vdtutorial.experiments.checkpoints import checkpoint_path, load_checkpoint

    torch.manual_seed(0)
    net = nn.Sequential(vd.LinearSVDO(6, 5), nn.ReLU(), vd.LinearSVDO(5, 3))
    with torch.no_grad():
        for layer in vd.svdo_layers(net):
            layer.log_sigma2.copy_(
                torch.where(torch.rand_like(layer.weight) < 0.4, 5.0, -10.0) + torch.log(layer.weight**2)
            )
    mu = load_checkpoint(checkpoint_path(Demos.load(demo_path("reach", 8000, 0.5, 0)).meta, "vd", "state", 0)).mu
    for module in (net, mu):
        assert vd.pruned_fraction(module) == sparsity_report(module).weight_fraction
    assert 0 < vd.pruned_fraction(net) < 1
