"""Chapter 07's trusted checks (vdtutorial/course/checks/ch07.py): the teacher's solutions pass them on every seed;
the graders' deliberately wrong answer, other plausible mistakes and an unsolved stub lose their exercise; the
feedback names no number."""

import copy

import numpy as np
import pytest
import torch

from check_support import UNSOLVED, answers, changed, executed, failures, stub
from vdtutorial.vd import THRESHOLD, svdo_layers

ANSWERS = answers("07_finetuning")
#: What the answer cells use from the chapter's first cells.
CONTEXT = {"copy": copy, "np": np, "torch": torch, "THRESHOLD": THRESHOLD, "svdo_layers": svdo_layers}


def run(exercise: str, source: str, seed: int) -> list[str]:
    """The grader's steps (inputs from a fresh seed, the probe, the verdict) on a namespace holding ``source``."""
    return failures(exercise, executed(CONTEXT, source), seed)


PRUNE, STEPS = ANSWERS["ch07_prune"], ANSWERS["ch07_steps_to_level"]


@pytest.mark.parametrize("seed", range(4))
def test_the_teachers_solutions_pass(seed):
    assert run("ch07_prune", PRUNE, seed) == []
    assert run("ch07_steps_to_level", STEPS, seed) == []


@pytest.mark.parametrize(
    "old, new",
    [
        ("keep = log_alpha <= threshold", "keep = log_alpha > threshold"),  # the graders' wrong answer
        ("keep = log_alpha <= threshold", "keep = log_alpha <= THRESHOLD"),  # ignores the threshold argument
        ("pruned = copy.deepcopy(policy)", "pruned = policy"),  # prunes the policy it was given
        ("            layer.log_sigma2.requires_grad_(False)\n", ""),  # alpha keeps training
        ("            layer.pruned.fill_(True)\n", ""),  # stays stochastic in train mode
        ("            layer.weight.mul_(keep)\n", ""),  # pruned weights stay in the copy
    ],
)
def test_wrong_pruning_loses(old, new):
    assert run("ch07_prune", changed(PRUNE, old, new), 0)


@pytest.mark.parametrize(
    "old, new",
    [
        ("smoothed >= level", "smoothed > level"),  # a level met exactly is reached
        ("mean[max(0, k - window + 1):k + 1]", "mean[max(0, k - window):k + 1]"),  # a window one too long
        ('[iterations[hits[0]]]["env_steps"]', '[iterations[hits[0]]]["iteration"]'),  # iterations, not env steps
        ('if row["method"] == method', 'if row["method"] != "expert"'),  # every method's rows mixed
    ],
)
def test_wrong_steps_to_level_loses(old, new):
    assert run("ch07_steps_to_level", changed(STEPS, old, new), 0)


def test_unsolved_stubs_lose():
    for exercise, source in (("ch07_prune", PRUNE), ("ch07_steps_to_level", STEPS)):
        assert run(exercise, stub(source), 0) == UNSOLVED
