"""Trusted checks of chapter 05's exercises: one ELBO step (5.1) and the cloning loop with the beta warm-up (5.2).

5.1: a small sparse-VD policy made from a seed, with weight noise large enough to change the loss, a random
mini-batch and a fresh optimiser. The kernel takes two of the student's steps from eval mode, seeding torch before
each; the grader takes the same two steps from the same policy with the library's log-likelihood
(:meth:`vdtutorial.policy.GaussianPolicy.log_prob`) and KL (:func:`vdtutorial.vd.model_kl`), as
:func:`vdtutorial.pretrain.pretrain` does, and compares the losses and both networks' parameters.

5.2: the student's ``clone_vd`` runs with a stand-in for ``elbo_step`` that records each call (row k of the
observations holds k) and returns the call's number as its loss. The grader checks the calls: every training row once
per epoch, in a fresh order that the seed decides, each action with its observation, the KL divided by the size of
the training set, beta rising linearly from 0 to 1 over the warm-up, one Adam on mu's parameters with the learning
rate asked for; and the mean loss of each epoch.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from functools import lru_cache

import numpy as np
import torch

from vdtutorial.course.checks import Check, Failures, swapped
from vdtutorial.envs.base import MAX_DELTA
from vdtutorial.envs.scene import CUP_REGION_HIGH, CUP_REGION_LOW
from vdtutorial.policy import make_policy
from vdtutorial.pretrain import observation_space
from vdtutorial.vd import model_kl, svdo_layers

#: Optimiser steps per case of 5.1: a second one finds gradients left over from the first.
STEPS = 2
#: Small networks (two layers per stream): the exercises do not depend on the sizes.
SIZES = {"scene_hidden": (16, 8), "joint_hidden": (16, 8)}


@lru_cache(maxsize=None)
def _space():
    """The reaching task's state observation space (built once per process)."""
    return observation_space("reach", "state")


def _policy(seed: int):
    """A small sparse-VD policy from ``seed``, with mu's log alpha between -4 and 0: weight noise that matters (at
    initialisation it is too small to tell a step with noise from one without)."""
    torch.manual_seed(seed)
    policy = make_policy(_space(), 6, variational=True, **SIZES)
    with torch.no_grad():
        for layer in svdo_layers(policy.mu):
            layer.log_sigma2.copy_(torch.log(layer.weight**2 + 1e-8) + 4 * torch.rand(layer.weight.shape) - 4)
    return policy


def _observations(rng, rows: int) -> np.ndarray:
    """Random reaching states: 6 joint angles, then the cup's x, y (on the table region) and z."""
    low = np.concatenate([np.full(6, -np.pi), CUP_REGION_LOW, [-0.01]])
    high = np.concatenate([np.full(6, np.pi), CUP_REGION_HIGH, [0.01]])
    return rng.uniform(low, high, (rows, 9))


def step_inputs(rng: np.random.Generator) -> dict:
    """Three mini-batches: beta 0 with Adam (the loss is then the mean NLL), a random beta and beta 1 with SGD."""
    cases = {}
    for k, beta in enumerate((0.0, rng.uniform(0.1, 0.9), 1.0)):
        rows = int(rng.integers(16, 65))
        cases[f"case{k}"] = {
            "beta": beta,
            "n_train": int(rng.integers(rows, 10000)),
            "obs": _observations(rng, rows),
            "actions": rng.uniform(-MAX_DELTA, MAX_DELTA, (rows, 6)),
            "adam": k == 0,
            "lr": 10 ** rng.uniform(-3, -1.5),
            "policy_seed": int(rng.integers(2**31)),
            "noise_seed": int(rng.integers(2**31 - STEPS)),
        }
    return cases


def _setup(case: dict):
    """The case's policy (in eval mode: the step must switch the weight noise on), optimiser and mini-batch."""
    policy = _policy(int(case["policy_seed"])).eval()
    kind = torch.optim.Adam if bool(case["adam"]) else torch.optim.SGD
    optimiser = kind(policy.mu.parameters(), lr=float(case["lr"]))
    obs, actions = (torch.as_tensor(case[name], dtype=torch.float32) for name in ("obs", "actions"))
    return policy, optimiser, obs, actions


def _flat(module) -> torch.Tensor:
    return torch.cat([p.detach().reshape(-1) for p in module.parameters()])


def step_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        policy, optimiser, obs, actions = _setup(case)
        losses, floats = [], []
        for k in range(STEPS):
            torch.manual_seed(int(case["noise_seed"]) + k)
            loss = namespace["elbo_step"](policy, optimiser, obs, actions, int(case["n_train"]), float(case["beta"]))
            floats.append(isinstance(loss, float))
            losses.append(float(loss))
        out[key] = {"losses": losses, "floats": floats, "mu": _flat(policy.mu), "sigma": _flat(policy.sigma)}
    return out


@contextmanager
def _one_thread():
    """Torch on one thread while the block runs: for networks this small, more threads only wait for each other."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def step_verdict(inputs: dict, outputs: dict) -> list[str]:
    with _one_thread():
        return _step_failures(inputs, outputs)


def _step_failures(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key], f"case {key[-1]}"
        policy, optimiser, obs, actions = _setup(case)
        sigma, beta, n_train = _flat(policy.sigma), float(case["beta"]), int(case["n_train"])
        losses = []
        for k in range(STEPS):
            torch.manual_seed(int(case["noise_seed"]) + k)
            policy.train()
            loss = -policy.log_prob(obs, actions).mean() + beta * model_kl(policy.mu) / n_train
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(loss.item())
        failures.true(got["floats"], f"{where}: return the loss as a Python float")
        failures.close(
            got["losses"],
            losses,
            f"{where}: the loss (the mean negative log-likelihood with the weight noise on, plus beta KL / N)",
            1e-4,
            1e-4,
        )
        failures.close(
            got["mu"],
            _flat(policy.mu),
            f"{where}: mu after the steps (each one step of the optimiser on "
            "that loss, from gradients of that loss alone)",
            1e-4,
            1e-6,
        )
        failures.close(got["sigma"], sigma, f"{where}: the sigma network must stay as it is", 0, 0)
    return failures


def loop_inputs(rng: np.random.Generator) -> dict:
    """Two data sets of 60 to 200 rows, a random share of them for training, at least three mini-batches per epoch."""
    cases = {}
    for k in range(2):
        n = int(rng.integers(60, 201))
        train = np.flatnonzero(rng.random(n) < rng.uniform(0.6, 0.95))
        seed = int(rng.integers(2**31 - 1000))
        cases[f"case{k}"] = {
            "actions": rng.normal(size=n),
            "train_idx": train,
            "epochs": int(rng.integers(2, 5)),
            "batch_size": int(rng.integers(10, len(train) // 3 + 1)),
            "warmup": rng.uniform(0.2, 0.8),
            "lr": 10 ** rng.uniform(-4, -2),
            "seed": seed,
            "other_seed": seed + int(rng.integers(1, 1000)),
        }
    return cases


def _record(namespace: dict, case: dict, seed: int) -> dict:
    """clone_vd on the case with ``seed``, elbo_step replaced by a recorder: what the calls got, what clone_vd
    returned."""
    n = len(case["actions"])
    obs = torch.arange(n, dtype=torch.float32)[:, None].repeat(1, 9)
    actions = torch.as_tensor(case["actions"], dtype=torch.float32)[:, None].repeat(1, 6)
    policy, calls = make_policy(_space(), 6, variational=True, **SIZES), []

    def recorder(policy_, optimiser, obs_, actions_, n_train, beta):
        calls.append(
            (
                torch.as_tensor(obs_)[:, 0].long(),
                torch.as_tensor(actions_)[:, 0],
                n_train,
                float(beta),
                optimiser,
                policy_,
            )
        )
        return float(len(calls))  # the "loss" of step k is k

    with swapped(namespace, elbo_step=recorder):
        history = namespace["clone_vd"](
            policy,
            obs,
            actions,
            case["train_idx"],
            int(case["epochs"]),
            batch_size=int(case["batch_size"]),
            lr=float(case["lr"]),
            warmup=float(case["warmup"]),
            seed=seed,
        )
    optimiser = calls[0][4] if calls else None
    groups = getattr(optimiser, "param_groups", [])
    return {
        "rows": torch.cat([c[0] for c in calls]) if calls else [],
        "sizes": [len(c[0]) for c in calls],
        "actions": torch.cat([c[1] for c in calls]) if calls else [],
        "n_train": [c[2] for c in calls],
        "beta": [c[3] for c in calls],
        "history": np.asarray(history, dtype=float),
        "adam": isinstance(optimiser, torch.optim.Adam),
        "one_optimiser": all(c[4] is optimiser for c in calls),
        "on_mu": {id(p) for g in groups for p in g["params"]} == {id(p) for p in policy.mu.parameters()},
        "lr": [g["lr"] for g in groups],
        "same_policy": all(c[5] is policy for c in calls),
    }


def loop_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key in sorted(inputs):
        case = inputs[key]
        out[key] = {
            "run": _record(namespace, case, int(case["seed"])),
            "again": _record(namespace, case, int(case["seed"]))["rows"],
            "other": _record(namespace, case, int(case["other_seed"]))["rows"],
        }
    return out


def loop_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in sorted(inputs):
        case, got, where = inputs[key], outputs[key]["run"], f"case {key[-1]}"
        train, epochs, size = np.asarray(case["train_idx"]), int(case["epochs"]), int(case["batch_size"])
        per_epoch = math.ceil(len(train) / size)
        total = epochs * per_epoch
        sizes = np.asarray(got["sizes"], dtype=int)
        if not failures.true(
            len(sizes) == total and np.all(sizes <= size) and np.shape(got["history"]) == (epochs,),
            f"{where}: one elbo_step per mini-batch of at most batch_size rows, the fewest "
            "mini-batches that cover the training rows in each epoch, and one mean loss per epoch",
        ):
            continue
        rows = np.asarray(got["rows"], dtype=int)
        orders = np.split(rows, np.cumsum(sizes)[per_epoch - 1 : -1 : per_epoch])
        failures.true(
            all(np.array_equal(np.sort(order), train) for order in orders),
            f"{where}: every epoch visits every training row exactly once (and no other row)",
        )
        failures.true(
            len({tuple(order) for order in orders}) == epochs and not np.array_equal(orders[0], np.sort(orders[0])),
            f"{where}: a fresh random order of the training rows in every epoch",
        )
        failures.equal(outputs[key]["again"], rows, f"{where}: the same seed must give the same order")
        failures.true(not np.array_equal(outputs[key]["other"], rows), f"{where}: another seed must give another order")
        failures.close(
            got["actions"],
            np.asarray(case["actions"], dtype=np.float32)[rows],
            f"{where}: each action must stay with its observation",
            0,
            1e-6,
        )
        failures.true(
            np.asarray(got["n_train"]) == len(train), f"{where}: the KL is divided by the size of the training set"
        )
        beta, warmup_steps = np.asarray(got["beta"], dtype=float), float(case["warmup"]) * total
        schedule = np.minimum(1, np.arange(total) / warmup_steps)
        failures.true(
            beta[0] == 0
            and beta[-1] == 1
            and np.all(np.diff(beta) >= 0)
            and np.allclose(beta, schedule, rtol=0, atol=1 / warmup_steps + 1e-9),  # off by one step at most
            f"{where}: beta rises from zero to one, linearly in the steps, over the warm-up share of them",
        )
        failures.true(got["adam"] and got["one_optimiser"], f"{where}: one torch.optim.Adam for all steps")
        failures.true(got["on_mu"], f"{where}: the optimiser holds mu's parameters, and no others")
        failures.true(
            len(got["lr"]) > 0 and np.all(np.asarray(got["lr"]) == case["lr"]),
            f"{where}: the optimiser's learning rate is lr",
        )
        failures.true(got["same_policy"], f"{where}: elbo_step gets the policy that clone_vd was given")
        mean_loss = [np.mean(np.arange(e * per_epoch, (e + 1) * per_epoch) + 1) for e in range(epochs)]
        failures.close(got["history"], mean_loss, f"{where}: return the mean loss of each epoch")
    return failures


CHECKS = [
    Check("ch05_elbo_step", step_inputs, step_probe, step_verdict),
    Check("ch05_clone_vd", loop_inputs, loop_probe, loop_verdict),
]
