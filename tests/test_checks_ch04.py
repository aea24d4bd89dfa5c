"""Chapter 04's trusted checks (vdtutorial/course/checks/ch04.py), run as the grader runs them: the teacher's solutions
pass on many draws, wrong answers and unsolved stubs fail, and no message gives a number away."""

import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from check_support import UNSOLVED, answers, executed, failures, notebook, stub
from vdtutorial import vd
from vdtutorial.course.checks import ch04

ANSWERS = answers("04_sparse_variational_dropout")
#: Mistakes a student could make, as (exercise, text of the teacher's solution, the mistaken version).
MISTAKES = {
    "one weight sample for the batch": ("ch04_gaussian_dropout", "* eps)", "* eps[:1])"),
    "noise of variance alpha^2": ("ch04_gaussian_dropout", "torch.exp(log_alpha / 2)", "torch.exp(log_alpha)"),
    "noise detached": (
        "ch04_gaussian_dropout",
        "torch.exp(log_alpha / 2) * eps",
        "torch.exp(log_alpha / 2).detach() * eps",
    ),
    "kl sign": ("ch04_svdo_layer", "- 0.5 * F.softplus(-self.log_alpha)", "+ 0.5 * F.softplus(-self.log_alpha)"),
    "no clipping": (
        "ch04_svdo_layer",
        "torch.clamp(self.log_sigma2 - torch.log(self.weight**2 + 1e-8), LOG_ALPHA_MIN, LOG_ALPHA_MAX)",
        "(self.log_sigma2 - torch.log(self.weight**2 + 1e-8))",
    ),
    "noise shared by the batch": ("ch04_svdo_layer", "torch.randn_like(mean)", "torch.randn_like(mean[:1])"),
    "unpruned eval": (
        "ch04_svdo_layer",
        "F.linear(x, self.weight * self.keep_mask(), self.bias)",
        "F.linear(x, self.weight, self.bias)",
    ),
    "dead-in only": ("ch04_compact", "gone = ~weights[k].any(1) | ~weights[k + 1].any(0)", "gone = ~weights[k].any(1)"),
    "constant dropped": (
        "ch04_compact",
        "biases[k + 1] += weights[k + 1][:, gone] @ torch.relu(biases[k][gone])",
        "pass",
    ),
}


def _namespace(**replaced) -> dict:
    context = {"math": math, "torch": torch, "nn": nn, "F": F, "LinearSVDO": vd.LinearSVDO}
    context.update(
        {
            name: getattr(vd, name)
            for name in ("K1", "K2", "K3", "LOG_ALPHA_MAX", "LOG_ALPHA_MIN", "LOG_SIGMA2_INIT", "THRESHOLD")
        }
    )
    cells = {**ANSWERS, **replaced}
    return executed(context, cells["ch04_gaussian_dropout"], cells["ch04_svdo_layer"], cells["ch04_compact"])


def test_the_checks_are_the_chapters_exercises_in_order():
    assert [item.exercise for item in ch04.CHECKS] == list(ANSWERS)


@pytest.mark.parametrize("exercise", list(ANSWERS))
def test_the_teachers_solution_passes_on_every_draw(exercise):
    torch.manual_seed(0)
    for seed in range(20):
        assert failures(exercise, _namespace(), seed) == [], seed


@pytest.mark.parametrize("mistake", sorted(MISTAKES))
def test_a_mistake_fails(mistake):
    exercise, right, wrong = MISTAKES[mistake]
    assert ANSWERS[exercise].count(right) == 1, right
    namespace = _namespace(**{exercise: ANSWERS[exercise].replace(right, wrong)})
    assert failures(exercise, namespace, 3)


@pytest.mark.parametrize("exercise", list(ANSWERS))
def test_an_unsolved_stub_fails(exercise):
    namespace = _namespace(**{exercise: stub(ANSWERS[exercise])})
    assert failures(exercise, namespace, 1) == UNSOLVED


def test_the_first_exercise_comes_before_the_1500th_word_of_markdown():
    """The chapter lets the learner build early: fewer than 1,500 words of markdown (all of them, folded ones
    included) before the first exercise's text."""
    cells = notebook("04_sparse_variational_dropout").cells
    first = next(k for k, cell in enumerate(cells) if cell.metadata.get("nbgrader", {}).get("solution"))
    words = sum(len(cell.source.split()) for cell in cells[: first - 1] if cell.cell_type == "markdown")
    assert cells[first - 1].source.startswith("### Exercise 4.1") and words < 1500, words
