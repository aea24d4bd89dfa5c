"""Trusted checks of chapter 11's exercises: the L1 strength that matches L2's penalty (11.1) and the L1 entry's
penalty (11.2).

Both exercises take a mean network and read its weight matrices. The inputs are random networks shaped like the
policy's mean network (two streams of linear layers with tanh between them, then a head; biases drawn non-zero, so
that a penalty on them shows), given to the kernel as plain arrays. The probe builds them from ``torch.nn`` alone,
calls the student's code and sends back what it returned, the gradients it left and the weights after the call.
The grader computes the answers from its own copy of the arrays with numpy:

11.1: ``l1_strength(mu, l2)`` is the lambda_1 at which ``lambda_1 * sum |W|`` equals ``l2 * sum W^2`` on mu's
weight matrices (biases excluded), returned as a Python float.

11.2: ``L1(..., strength=s).penalty(mu, at)`` is ``s * sum |W|`` over mu's weight matrices, added to the mean
negative log-likelihood as the L2 entry's term is (nothing divides it), so the gradient it leaves is ``s * sign(W)``
on every weight and zero on every bias. ``at`` is a stand-in for the cloning step whose numbers (the step, the
training split's size, the config's L2 coefficient) are drawn apart from ``s``: a penalty that reads them shows.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch
from torch import nn

from vdtutorial.course.checks import Check, Failures

#: The layers of a case's network, in the order of its ``named_parameters``: (stream, index in the stream).
LAYERS = ("s0a", "s0b", "s1a", "head")
#: Cases per exercise.
CASES = 4


def _network_inputs(rng: np.random.Generator) -> dict:
    """A random mean network: stream 0 two layers, stream 1 one layer, a head on both streams' outputs."""
    n_in0, hidden, out0, n_in1, out1, actions = rng.integers(2, 13, 6)
    shapes = {"s0a": (hidden, n_in0), "s0b": (out0, hidden), "s1a": (out1, n_in1), "head": (actions, out0 + out1)}
    scale = rng.uniform(0.05, 1.0)
    return {
        name: {"weight": rng.normal(0, scale, shape), "bias": rng.normal(0, scale, shape[0])}
        for name, shape in shapes.items()
    }


def _linear(layer: dict) -> nn.Linear:
    weight = torch.as_tensor(np.asarray(layer["weight"]), dtype=torch.float64)
    linear = nn.Linear(weight.shape[1], weight.shape[0]).double()
    with torch.no_grad():
        linear.weight.copy_(weight)
        linear.bias.copy_(torch.as_tensor(np.asarray(layer["bias"]), dtype=torch.float64))
    return linear


def _network(layers: dict) -> nn.Module:
    """The case's network as ``torch.nn`` modules, named like the policy's mean network (``streams.0.0.weight``...)."""
    streams = nn.ModuleList(
        [
            nn.Sequential(_linear(layers["s0a"]), nn.Tanh(), _linear(layers["s0b"]), nn.Tanh()),
            nn.Sequential(_linear(layers["s1a"]), nn.Tanh()),
        ]
    )
    return nn.ModuleDict({"streams": streams, "head": nn.Sequential(_linear(layers["head"]))})


def _parameters(network: nn.Module) -> dict:
    """The network's weights and biases after the student's call, by layer, as arrays."""
    linears = [m for m in network.modules() if isinstance(m, nn.Linear)]
    return {name: {"weight": m.weight.detach(), "bias": m.bias.detach()} for name, m in zip(LAYERS, linears)}


def _weights(layers: dict) -> list[np.ndarray]:
    return [np.asarray(layers[name]["weight"], dtype=float) for name in LAYERS]


def _unchanged(failures: Failures, got: dict, layers: dict, where: str) -> None:
    same = all(
        np.array_equal(np.asarray(got[name][kind], dtype=float), np.asarray(layers[name][kind], dtype=float))
        for name in LAYERS
        for kind in ("weight", "bias")
    )
    failures.true(same, f"{where}: the network must stay as it is (no parameter changed)")


def strength_inputs(rng: np.random.Generator) -> dict:
    """Networks of random sizes and weight scales, with L2 coefficients from 1e-6 to 1e-2."""
    return {f"case{k}": {"layers": _network_inputs(rng), "l2": float(10 ** rng.uniform(-6, -2))} for k in range(CASES)}


def strength_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        network = _network(case["layers"])
        found = namespace["l1_strength"](network, float(case["l2"]))
        out[key] = {"strength": float(found), "is_float": isinstance(found, float), "after": _parameters(network)}
    return out


def strength_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"case {key[4:]}"
        weights = _weights(case["layers"])
        want = float(case["l2"]) * sum((w**2).sum() for w in weights) / sum(np.abs(w).sum() for w in weights)
        failures.true(bool(got["is_float"]), f"{where}: return the strength as a Python float")
        failures.close(
            [float(got["strength"])],
            [want],
            f"{where}: the strength at which L1's penalty on the weight matrices (biases excluded) equals L2's",
            1e-5,
            0,
        )
        _unchanged(failures, got["after"], case["layers"], where)
    return failures


def penalty_inputs(rng: np.random.Generator) -> dict:
    """Networks as above, a strength from 1e-5 to 1e-1, and a cloning step whose numbers differ from the strength."""
    cases = {}
    for k in range(CASES):
        total = int(rng.integers(10, 10_000))
        cases[f"case{k}"] = {
            "layers": _network_inputs(rng),
            "strength": float(10 ** rng.uniform(-5, -1)),
            "step": int(rng.integers(0, total)),
            "total_steps": total,
            "n_train": int(rng.integers(50, 20_000)),
            "config_l2": float(10 ** rng.uniform(-6, -2)),
        }
    return cases


def penalty_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        network = _network(case["layers"])
        entry = namespace["L1"](name="l1", label="L1", colour="tab:purple", strength=float(case["strength"]))
        at = SimpleNamespace(
            step=int(case["step"]),
            total_steps=int(case["total_steps"]),
            n_train=int(case["n_train"]),
            config=SimpleNamespace(l2=float(case["config_l2"])),
        )
        term = entry.penalty(network, at)
        differentiable = isinstance(term, torch.Tensor) and term.requires_grad and term.numel() == 1
        if differentiable:
            term.backward()
        linears = [m for m in network.modules() if isinstance(m, nn.Linear)]
        grads = {
            name: {
                kind: torch.zeros_like(getattr(m, kind)) if getattr(m, kind).grad is None else getattr(m, kind).grad
                for kind in ("weight", "bias")
            }
            for name, m in zip(LAYERS, linears)
        }
        out[key] = {
            "value": float(term.detach()) if isinstance(term, torch.Tensor) else float(term),
            "is_tensor": isinstance(term, torch.Tensor),
            "differentiable": differentiable,
            "grads": grads,
            "after": _parameters(network),
        }
    return out


def penalty_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"case {key[4:]}"
        strength, weights = float(case["strength"]), _weights(case["layers"])
        failures.close(
            [float(got["value"])],
            [strength * sum(np.abs(w).sum() for w in weights)],
            f"{where}: the penalty (the strength times the sum of |W| over mu's weight matrices, biases excluded, "
            "and nothing else: no division by the cloning step's numbers)",
            1e-5,
            0,
        )
        failures.true(
            bool(got["is_tensor"]) and bool(got["differentiable"]),
            f"{where}: return a one-number torch tensor that carries the gradient (cloning back-propagates through it)",
        )
        if bool(got["differentiable"]):
            grads = got["grads"]
            failures.close(
                np.concatenate([np.asarray(grads[name]["weight"], dtype=float).ravel() for name in LAYERS]),
                np.concatenate([strength * np.sign(w).ravel() for w in weights]),
                f"{where}: the gradient on every weight matrix (every layer of mu counts, the head's too)",
                1e-5,
                1e-12,
            )
            failures.close(
                np.concatenate([np.asarray(grads[name]["bias"], dtype=float).ravel() for name in LAYERS]),
                np.zeros(sum(len(case["layers"][name]["bias"]) for name in LAYERS)),
                f"{where}: the gradient on the biases (L1 on the weights leaves them alone)",
                0,
                1e-12,
            )
        _unchanged(failures, got["after"], case["layers"], where)
    return failures


CHECKS = [
    Check("ch11_l1_strength", strength_inputs, strength_probe, strength_verdict),
    Check("ch11_l1_penalty", penalty_inputs, penalty_probe, penalty_verdict),
]
