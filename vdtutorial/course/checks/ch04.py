"""Trusted checks of chapter 04's exercises: Gaussian dropout on a linear layer's weights (4.1), the sparse VD layer
(4.2) and compaction (4.3).

Each layer or network is made from arrays the grader drew; the kernel returns the student's numbers (outputs under
the drawn noise, log alpha, masks, KL, forward passes, gradients, the compacted network's weights) and the grader
recomputes them: eq. 4 by autograd, then with :class:`vdtutorial.vd.LinearSVDO` and
:func:`vdtutorial.analysis.compact.compact`.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from vdtutorial.analysis.compact import compact
from vdtutorial.course.checks import Check, Failures
from vdtutorial.vd import LOG_ALPHA_MAX, LOG_ALPHA_MIN, LOG_SIGMA2_INIT, LinearSVDO

#: Samples of the training-mode forward pass per input: the mean and variance are checked to a few standard errors.
REPEATS = 20000
_PARAMETERS = ("weight", "bias", "log_sigma2")


def dropout_inputs(rng: np.random.Generator) -> dict:
    """Three mini-batches through random layers, log alpha from almost no noise to far past the threshold, with the
    standard normal noise of eq. 4 drawn for every example and weight."""
    cases = {}
    for k in range(3):
        n, n_in, n_out = int(rng.integers(1, 9)), int(rng.integers(1, 9)), int(rng.integers(1, 6))
        cases[f"case{k}"] = {
            "x": rng.normal(size=(n, n_in)),
            "weight": rng.normal(0, 0.5, (n_out, n_in)),
            "bias": rng.normal(size=n_out),
            "log_alpha": rng.uniform(-8, 6, (n_out, n_in)),
            "eps": rng.normal(size=(n, n_out, n_in)),
            "cotangent": rng.normal(size=(n, n_out)),
        }
    return cases


#: The parameters of 4.1's layer whose gradients the check compares (reparameterised: they flow through the noise).
_TRAINED = ("weight", "bias", "log_alpha")


def _dropout_tensors(case: dict) -> dict:
    return {
        name: torch.tensor(np.asarray(case[name]), dtype=torch.float64, requires_grad=name in _TRAINED)
        for name in ("x", "weight", "bias", "log_alpha", "eps")
    }


def dropout_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        given = _dropout_tensors(case)
        y = namespace["gaussian_dropout_linear"](*given.values())
        got = {"y": y}
        if torch.is_tensor(y) and y.requires_grad and y.shape == np.shape(case["cotangent"]):
            grads = torch.autograd.grad(
                y, [given[name] for name in _TRAINED], torch.as_tensor(case["cotangent"]), allow_unused=True
            )
            got["grads"] = {name: torch.zeros_like(given[name]) if g is None else g for name, g in zip(_TRAINED, grads)}
        out[key] = got
    return out


def dropout_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"mini-batch {key[4:]}"
        given = _dropout_tensors(case)
        weights = given["weight"] * (1 + torch.exp(given["log_alpha"] / 2) * given["eps"])  # eq. 4, per example
        want = torch.einsum("mi,moi->mo", given["x"], weights) + given["bias"]
        if not failures.close(
            got["y"],
            want.detach().numpy(),
            f"{where}: the outputs, each example through its own weights sampled by eq. 4 with its noise eps[m]",
            1e-9,
            1e-12,
        ):
            continue
        if not failures.true(
            "grads" in got,
            f"{where}: autograd must differentiate the outputs with respect to "
            "weight, bias and log_alpha (keep them in the graph)",
        ):
            continue
        grads = torch.autograd.grad(want, [given[name] for name in _TRAINED], torch.as_tensor(case["cotangent"]))
        for name, grad in zip(_TRAINED, grads):
            failures.close(
                got["grads"][name], grad.numpy(), f"{where}: the gradient with respect to {name}", 1e-9, 1e-12
            )
    return failures


def _layer_arrays(rng, n_in, n_out):
    weight = rng.normal(0, 0.5, (n_out, n_in))
    return {
        "weight": weight,
        "bias": rng.normal(size=n_out),
        "log_sigma2": np.log(weight**2) + rng.uniform(-10, 10, (n_out, n_in)),
    }


def layer_inputs(rng: np.random.Generator) -> dict:
    """Two random layers (log alpha on both sides of the threshold) and one at the clipping bounds."""
    cases = {}
    for k in range(2):
        n_in, n_out = int(rng.integers(2, 13)), int(rng.integers(1, 9))
        cases[f"case{k}"] = {
            **_layer_arrays(rng, n_in, n_out),
            "x": 2 * rng.normal(size=(1, n_in)),
            "batch": rng.normal(size=(6, n_in)),
        }
    cases["case2"] = {
        "weight": np.array([[3.0, -2.0, 1e-7], [0.0, 1.0, 0.5]]),
        "bias": rng.normal(size=2),
        "log_sigma2": np.array([[-30.0, 20.0, -9.0], [0.0, -3.0, -1.0]]),
        "x": rng.normal(size=(1, 3)),
        "batch": rng.normal(size=(4, 3)),
    }
    return {**cases, "torch_seed": int(rng.integers(2**31))}


def layer_probe(namespace: dict, inputs: dict) -> dict:
    torch.manual_seed(int(inputs["torch_seed"]))
    out = {}
    for key in sorted(k for k in inputs if k.startswith("case")):
        case = {name: torch.as_tensor(inputs[key][name], dtype=torch.float32) for name in inputs[key]}
        n_out, n_in = case["weight"].shape
        layer = namespace["MyLinearSVDO"](n_in, n_out)
        named = dict(layer.named_parameters())
        got = {
            "initial_weight": layer.weight.detach().clone(),
            "initial_log_sigma2": layer.log_sigma2.detach().clone(),
            "bias_shape": layer.bias.shape,
            "parameters": [name in named for name in _PARAMETERS],
        }
        with torch.no_grad():
            for name in _PARAMETERS:
                getattr(layer, name).copy_(case[name])
        got.update(log_alpha=layer.log_alpha, keep=layer.keep_mask(), kl=layer.kl())
        layer.train()
        with torch.no_grad():
            got["samples"] = layer(case["x"].expand(REPEATS, -1))
        layer.zero_grad()
        (layer(case["batch"]).pow(2).sum() + layer.kl()).backward()
        got["grad_weight"], got["grad_log_sigma2"] = (
            torch.zeros(1) if p.grad is None else p.grad for p in (layer.weight, layer.log_sigma2)
        )
        layer.eval()
        with torch.no_grad():
            got["eval"] = layer(case["batch"])
        out[key] = got
    return out


def _library_layer(case) -> LinearSVDO:
    n_out, n_in = case["weight"].shape
    layer = LinearSVDO(n_in, n_out)
    with torch.no_grad():
        for name in _PARAMETERS:
            getattr(layer, name).copy_(torch.as_tensor(case[name], dtype=torch.float32))
    return layer.eval()


def layer_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(k for k in inputs if k.startswith("case")):
        case, got, where = inputs[key], outputs[key], f"layer {key[-1]}"
        ref = _library_layer(case)
        n_out, n_in = case["weight"].shape
        bound = 1 / math.sqrt(n_in)
        failures.true(
            np.shape(got["initial_weight"]) == np.shape(got["initial_log_sigma2"]) == (n_out, n_in)
            and tuple(got["bias_shape"]) == (n_out,),
            f"{where}: the parameters' shapes",
        )
        failures.true(got["parameters"], f"{where}: weight, bias and log_sigma2 must be nn.Parameters")
        failures.true(np.all(got["initial_log_sigma2"] == LOG_SIGMA2_INIT), f"{where}: log sigma^2's initial value")
        initial = np.abs(got["initial_weight"])
        failures.true(0 < initial.max() <= bound + 1e-7, f"{where}: theta's initial distribution")
        with torch.no_grad():
            failures.close(got["log_alpha"], ref.log_alpha, f"{where}: log alpha", 1e-4, 1e-5)
            failures.equal(got["keep"], ref.keep_mask(), f"{where}: keep_mask()")
            failures.close(got["kl"], ref.kl(), f"{where}: kl()", 1e-4, 1e-4)
            x = torch.as_tensor(case["x"], dtype=torch.float32)
            mean = nn.functional.linear(x, ref.weight, ref.bias)[0].numpy()
            var = nn.functional.linear(x**2, ref.log_sigma2.exp())[0].numpy()
            samples = np.asarray(got["samples"], dtype=float)
            if failures.true(samples.shape == (REPEATS, n_out), f"{where}: training mode gives one output per example"):
                failures.true(
                    np.abs(samples.mean(0) - mean) < 6 * np.sqrt(var / REPEATS) + 1e-5,
                    f"{where}: training mode's mean output",
                )
                failures.true(
                    np.abs(samples.var(0) / var - 1) < 0.1,
                    f"{where}: training mode's variance, with fresh noise for every example",
                )
            failures.close(
                got["eval"],
                ref(torch.as_tensor(case["batch"], dtype=torch.float32)),
                f"{where}: eval mode's output",
                1e-4,
                1e-5,
            )
        failures.true(np.abs(got["grad_log_sigma2"]).sum() > 0, f"{where}: log sigma^2 gets a gradient")
        failures.true(np.abs(got["grad_weight"]).sum() > 0, f"{where}: theta gets a gradient")
        if key == "case2":
            failures.true(
                np.min(got["log_alpha"]) == LOG_ALPHA_MIN and np.max(got["log_alpha"]) == LOG_ALPHA_MAX,
                "log alpha is clipped to [LOG_ALPHA_MIN, LOG_ALPHA_MAX]",
            )
    return failures


def _pruned_net_arrays(rng, sizes):
    layers = []
    for n_in, n_out in zip(sizes[:-1], sizes[1:]):
        bound = 1 / math.sqrt(n_in)
        log_sigma2 = np.full((n_out, n_in), LOG_SIGMA2_INIT)
        log_sigma2[rng.random(n_out) < 0.3] = 20.0  # dead-in units of this layer
        log_sigma2[:, rng.random(n_in) < 0.3] = 20.0  # dead-out units of the layer before
        layers.append(
            {
                "weight": rng.uniform(-bound, bound, (n_out, n_in)),
                "bias": rng.normal(size=n_out),
                "log_sigma2": log_sigma2,
            }
        )
    return {f"layer{k}": layer for k, layer in enumerate(layers)}


def compact_inputs(rng: np.random.Generator) -> dict:
    """Three networks of 3 or 4 sparse VD layers with random pruned rows and columns, and a batch for each."""
    nets = {}
    for k in range(3):
        sizes = [int(rng.integers(3, 9)) for _ in range(int(rng.integers(4, 6)))]
        nets[f"net{k}"] = {**_pruned_net_arrays(rng, sizes), "x": rng.normal(size=(16, sizes[0]))}
    return nets


def _network(net: dict) -> nn.Sequential:
    layers = []
    for k in range(sum(key.startswith("layer") for key in net)):
        layers += [_library_layer(net[f"layer{k}"]), nn.ReLU()]
    return nn.Sequential(*layers[:-1]).eval()


def compact_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        net, x = _network(inputs[key]), torch.as_tensor(inputs[key]["x"], dtype=torch.float32)
        with torch.no_grad():
            result = namespace["my_compact"](net)
            got = {
                "after": net.eval()(x),
                "sequential": isinstance(result, nn.Sequential),
                "plain": [type(m) in (nn.Linear, nn.ReLU) for m in result]
                if isinstance(result, nn.Sequential)
                else [False],
            }
            linear = [m for m in result if type(m) is nn.Linear] if got["sequential"] else []
            got["layers"] = {f"{k}": {"weight": m.weight, "bias": m.bias} for k, m in enumerate(linear)}
            got["relu_after"] = (
                [type(a) is nn.Linear and type(b) is nn.ReLU for a, b in zip(result, result[1:])]
                if got["sequential"]
                else [False]
            )
        out[key] = got
    return out


def compact_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        where, got = f"network {key[-1]}", outputs[key]
        net = _network(inputs[key])
        x = torch.as_tensor(inputs[key]["x"], dtype=torch.float32)
        with torch.no_grad():
            before = net(x).numpy()
            library = [m.out_features for m in compact(net) if isinstance(m, nn.Linear)]
        failures.close(got["after"], before, f"{where}: my_compact must not change net", 0, 0)
        if not failures.true(
            got["sequential"] and np.all(got["plain"]),
            f"{where}: return an nn.Sequential of plain nn.Linear and nn.ReLU layers",
        ):
            continue
        count = len(got.get("layers", {}))
        weights = [np.asarray(got["layers"][f"{k}"]["weight"], dtype=float) for k in range(count)]
        biases = [np.asarray(got["layers"][f"{k}"]["bias"], dtype=float) for k in range(count)]
        if not failures.true(
            count == len(library)
            and int(np.sum(got["relu_after"])) == count - 1
            and weights[0].shape[1] == x.shape[1]
            and weights[-1].shape[0] == library[-1],
            f"{where}: one nn.Linear per layer, an nn.ReLU between them, same input and output sizes",
        ):
            continue
        value = x.numpy().astype(float)
        for k, (w, b) in enumerate(zip(weights, biases)):
            value = value @ w.T + b
            value = np.maximum(value, 0) if k < count - 1 else value
        failures.close(value, before, f"{where}: the compacted network's function", 1e-4, 1e-4)
        failures.true(all(w.shape[0] <= n for w, n in zip(weights, library)), f"{where}: remove every pruned unit")
    return failures


CHECKS = [
    Check("ch04_gaussian_dropout", dropout_inputs, dropout_probe, dropout_verdict),
    Check("ch04_svdo_layer", layer_inputs, layer_probe, layer_verdict),
    Check("ch04_compact", compact_inputs, compact_probe, compact_verdict),
]
