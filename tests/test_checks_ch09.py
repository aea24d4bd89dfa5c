"""Chapter 09's trusted checks (vdtutorial/course/checks/ch09.py): the teacher's solutions pass them on every seed;
the graders' deliberately wrong answer, other plausible mistakes and an unsolved stub lose their exercise; the
feedback names no number."""

import ast

import numpy as np
import pytest

from check_support import UNSOLVED, answers, changed, executed, failures, notebook, stub
from vdtutorial.beyond.dagger import BETA
from vdtutorial.beyond.imitation_rounds import cloning_config
from vdtutorial.envs.scene import N_JOINTS
from vdtutorial.pretrain import split_by_episode

ANSWERS = answers("09_beyond_the_paper")
#: What the answer cells use from the chapter's first cells.
CONTEXT = {
    "np": np,
    "N_JOINTS": N_JOINTS,
    "START_SIGMA": 0.05,
    "BETA": BETA,  # the chapter's START_SIGMA
    "cloning_config": cloning_config,
    "split_by_episode": split_by_episode,
}


def chapter_helper() -> str:
    """The chapter's own ``held_out_states``, which dart_plan calls (its cell also trains a policy: only the
    function is taken)."""
    cell = next(c for c in notebook("09_beyond_the_paper").cells if c.get("id") == "ch09-dart-byhand")
    node = next(n for n in ast.parse(cell.source).body if getattr(n, "name", None) == "held_out_states")
    return ast.get_source_segment(cell.source, node)


def run(exercise: str, source: str, seed: int) -> list[str]:
    """The grader's steps (inputs from a fresh seed, the probe, the verdict) on a namespace holding the chapter's
    helper and ``source``."""
    return failures(exercise, executed(CONTEXT, HELPER, source), seed)


DART, DAGGER, HELPER = ANSWERS["ch09_dart_noise"], ANSWERS["ch09_dagger_plan"], chapter_helper()


@pytest.mark.parametrize("seed", range(20))
def test_the_teachers_solutions_pass(seed):
    """Both checks test a distribution: a correct plan passes on every seed."""
    assert run("ch09_dart_noise", DART, seed) == []
    assert run("ch09_dagger_plan", DAGGER, seed) == []


@pytest.mark.parametrize(
    "old, new",
    [
        ("errors.T @ errors / len(errors)", "errors.T @ errors"),  # the graders' wrong answer
        ("errors.T @ errors / len(errors)", "np.cov(errors.T, bias=True)"),  # centred: loses the errors' mean
        ("        policy.eval()\n", ""),  # errors of a weight sample
        ("demos.states[held_out]", "demos.states"),  # the training states too
        (
            "factor @ rng.standard_normal(N_JOINTS)",  # independent joints: the noise
            "np.sqrt(np.diag(covariance)) * rng.standard_normal(N_JOINTS)",
        ),  # loses Sigma's correlations
        ("START_SIGMA ** 2 * np.eye", "START_SIGMA * np.eye"),  # Sigma_0 a standard deviation
    ],
)
def test_wrong_dart_loses(old, new):
    source = changed(DART, old, new)
    if old == "demos.states[held_out]":  # with the labels of the same states
        source = changed(source, "demos.actions[held_out]", "demos.actions")
    assert run("ch09_dart_noise", source, 0)


@pytest.mark.parametrize(
    "old, new",
    [
        ("    policy.eval()\n", ""),  # the learner samples its weights
        ("beta = BETA ** k", "beta = BETA * k"),  # the wrong schedule
        ("if rng.random() < beta:", "if rng.random() > beta:"),  # the expert's share is 1 - beta
        ("policy.act(state, deterministic=True)", "policy.act(state)"),  # a sampled action
    ],
)
def test_wrong_dagger_loses(old, new):
    assert run("ch09_dagger_plan", changed(DAGGER, old, new), 0)


def test_unsolved_stubs_lose():
    for exercise, source in (("ch09_dart_noise", DART), ("ch09_dagger_plan", DAGGER)):
        assert run(exercise, stub(source), 0) == UNSOLVED
