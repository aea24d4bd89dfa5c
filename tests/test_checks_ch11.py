"""Chapter 11's trusted checks (vdtutorial/course/checks/ch11.py): the teacher's solutions pass them on every seed;
the graders' deliberately wrong answer, other plausible mistakes (L2's squares instead of L1's absolute values, the
strength left out or divided by the training set's size, the biases penalised, a number instead of a tensor) and an
unsolved stub lose their exercise; the feedback names no number."""

from dataclasses import dataclass

import pytest
import torch

from check_support import UNSOLVED, answers, changed, executed, failures, stub
from vdtutorial.methods import CloningStep, Method
from vdtutorial.pretrain import PretrainConfig

ANSWERS = answers("11_your_method")
#: What the answer cells use from the chapter's first cells.
CONTEXT = {
    "torch": torch,
    "dataclass": dataclass,
    "Method": Method,
    "CloningStep": CloningStep,
    "PretrainConfig": PretrainConfig,
}
STRENGTH, PENALTY = ANSWERS["ch11_l1_strength"], ANSWERS["ch11_l1_penalty"]


def run(exercise: str, source: str, seed: int) -> list[str]:
    """The grader's steps (inputs from a fresh seed, the probe, the verdict) on a namespace holding ``source``."""
    return failures(exercise, executed(CONTEXT, source), seed)


@pytest.mark.parametrize("seed", range(6))
def test_the_teachers_solutions_pass(seed):
    assert run("ch11_l1_strength", STRENGTH, seed) == []
    assert run("ch11_l1_penalty", PENALTY, seed) == []


@pytest.mark.parametrize(
    "old, new, words",
    [
        (
            "w.abs().sum() for w in weights)\n        return",
            "(w**2).sum() for w in weights)\n        return",
            "penalty",
        ),
        ("return self.strength * total", "return total", "penalty"),  # the strength left out
        ("return self.strength * total", "return self.strength * total / at.n_train", "penalty"),  # scaled like VD's
        ("return self.strength * total", "return at.config.l2 * total", "penalty"),  # L2's coefficient, not its own
        ('if name.endswith("weight")]\n        total', "]\n        total", "penalty"),  # the biases penalised too
        ("return self.strength * total", "return float(self.strength * total)", "gradient"),  # a number, no gradient
        (
            "w.abs().sum() for w in weights)\n        return",
            "w.abs().mean() for w in weights)\n        return",
            "penalty",
        ),
    ],
)
def test_wrong_penalties_lose(old, new, words):
    found = run("ch11_l1_penalty", changed(PENALTY, old, new), 0)
    assert found and any(words in message for message in found), found


def test_the_graders_wrong_answer_is_l2_in_place_of_l1():
    """tests/test_classroom.py's wrong version of this chapter: squares for absolute values, the mistake of writing
    the L2 entry again."""
    assert run("ch11_l1_penalty", changed(PENALTY, "w.abs().sum()", "(w**2).sum()"), 0)


@pytest.mark.parametrize(
    "old, new",
    [
        ("l2 * squares / absolutes", "l2 * absolutes / squares"),  # the ratio upside down
        ('if name.endswith("weight")]', "]"),  # the biases counted
        ("return float(l2 * squares / absolutes)", "return l2 * squares / absolutes"),  # a tensor, not a float
        ("return float(l2 * squares / absolutes)", "return float(l2)"),  # the same strength as L2's
    ],
)
def test_wrong_strengths_lose(old, new):
    assert run("ch11_l1_strength", changed(STRENGTH, old, new), 0)


def test_a_strength_that_changes_the_network_loses():
    source = changed(
        STRENGTH, "    return float(", "    for w in weights:\n        w.data.mul_(0.5)\n    return float("
    )
    assert any("stay as it is" in message for message in run("ch11_l1_strength", source, 0))


def test_unsolved_stubs_lose():
    for exercise, source in (("ch11_l1_strength", STRENGTH), ("ch11_l1_penalty", PENALTY)):
        assert run(exercise, stub(source), 0) == UNSOLVED
