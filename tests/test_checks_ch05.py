"""Chapter 05's trusted checks (vdtutorial/course/checks/ch05.py), run as the grader runs them: the teacher's solutions
pass, wrong answers and unsolved stubs fail, and no message gives a number away."""

import math

import numpy as np
import pytest
import torch

from check_support import UNSOLVED, answers, changed, executed, failures, stub
from vdtutorial.course.checks import ch05
from vdtutorial.vd import model_kl

ANSWERS = answers("05_pretraining")


def _namespace(**replaced) -> dict:
    """The chapter's globals that the answer cells use, then the answer cells (the teacher's, unless replaced)."""
    cells = {**ANSWERS, **replaced}
    return executed(
        {"np": np, "torch": torch, "math": math, "model_kl": model_kl}, cells["ch05_elbo_step"], cells["ch05_clone_vd"]
    )


def test_the_checks_are_the_chapters_exercises_in_order():
    assert [item.exercise for item in ch05.CHECKS] == list(ANSWERS)


@pytest.mark.parametrize("exercise, seeds", [("ch05_elbo_step", range(6)), ("ch05_clone_vd", range(20))])
def test_the_teachers_solutions_pass(exercise, seeds):
    namespace = _namespace()
    for seed in seeds:
        assert failures(exercise, namespace, seed) == [], seed


def test_clone_vd_is_checked_without_the_students_elbo_step():
    namespace = _namespace(ch05_elbo_step=stub(ANSWERS["ch05_elbo_step"]))
    saved = namespace["elbo_step"]
    assert failures("ch05_clone_vd", namespace, 1) == []
    assert namespace["elbo_step"] is saved  # the probe put the chapter's elbo_step back


WRONG_STEPS = {
    "KL subtracted (the graders' wrong answer)": (
        "nll + beta * model_kl(policy.mu) / n_train",
        "nll - beta * model_kl(policy.mu) / n_train",
    ),
    "KL divided by the batch size": ("/ n_train", "/ len(obs)"),
    "weight noise left off": ("    policy.train()", "    pass"),
    "old gradients kept": ("    optimiser.zero_grad()\n", ""),
    "a tensor returned": ("return loss.item()", "return loss.detach()"),
}


@pytest.mark.parametrize("case", WRONG_STEPS)
def test_a_wrong_step_fails(case):
    old, new = WRONG_STEPS[case]
    assert failures("ch05_elbo_step", _namespace(ch05_elbo_step=changed(ANSWERS["ch05_elbo_step"], old, new)), 0)


WRONG_LOOPS = {
    "beta by epochs": (
        ("beta = min(1.0, step / (warmup * total_steps))", "beta = min(1.0, epoch / (warmup * epochs))"),
        "beta",
    ),
    "no shuffling": (("order, losses = rng.permutation(train_idx), []", "order, losses = train_idx, []"), "order"),
    "KL divided by the batch size": (("len(train_idx), beta)", "len(idx), beta)"), "KL"),
    "SGD": (("torch.optim.Adam(", "torch.optim.SGD("), "Adam"),
    "last loss instead of the mean": (("float(np.mean(losses))", "float(losses[-1])"), "mean loss"),
}


@pytest.mark.parametrize("case", WRONG_LOOPS)
def test_a_wrong_loop_fails(case):
    (old, new), word = WRONG_LOOPS[case]
    found = failures("ch05_clone_vd", _namespace(ch05_clone_vd=changed(ANSWERS["ch05_clone_vd"], old, new)), 0)
    assert any(word in message for message in found), found


@pytest.mark.parametrize("exercise", ["ch05_elbo_step", "ch05_clone_vd"])
def test_an_unsolved_stub_fails(exercise):
    found = failures(exercise, _namespace(**{exercise: stub(ANSWERS[exercise])}), 0)
    assert found == UNSOLVED
