"""Chapter 03's trusted checks (vdtutorial/course/checks/ch03.py), run as the grader runs them: the teacher's solutions
pass, wrong answers and unsolved stubs fail, and no message gives a number away."""

import numpy as np
import pytest

from check_support import UNSOLVED, answers, changed, executed, failures, stub
from vdtutorial.course import checks
from vdtutorial.course.checks import ch03
from vdtutorial.demos import ARRAYS, Demos, generate_demos
from vdtutorial.envs.base import HORIZON

ANSWERS = answers("03_demonstrations")


def _namespace(**replaced) -> dict:
    """The chapter's globals that the answer cells use, then the answer cells (the teacher's, unless replaced)."""
    cells = {**ANSWERS, **replaced}
    context = {"np": np, "HORIZON": HORIZON, "Demos": Demos}
    return executed(context, cells["ch03_noisy_rollout"], cells["ch03_rollout_demos"])


def test_the_checks_are_the_chapters_exercises_in_order():
    assert [item.exercise for item in ch03.CHECKS] == list(ANSWERS)


@pytest.mark.parametrize("exercise, seeds", [("ch03_noisy_rollout", range(3)), ("ch03_rollout_demos", range(8))])
def test_the_teachers_solutions_pass(exercise, seeds):
    namespace = _namespace()
    for seed in seeds:
        assert failures(exercise, namespace, seed) == [], seed


def test_rollout_demos_is_checked_without_the_students_noisy_rollout():
    namespace = _namespace(ch03_noisy_rollout=stub(ANSWERS["ch03_noisy_rollout"]))
    saved = {name: namespace.get(name) for name in ("noisy_rollout", "env", "expert")}
    assert failures("ch03_rollout_demos", namespace, 1) == []
    assert {name: namespace.get(name) for name in saved} == saved  # the probe put the chapter's globals back


def test_the_grader_puts_the_library_data_set_together_as_generate_demos_does():
    inputs = checks.nested(checks.plain(ch03.demos_inputs(np.random.default_rng(3))))
    case = inputs["case2"]
    seeds, want = ch03._expected(case, ch03._reach("verdict")[0])
    library = generate_demos("reach", int(case["samples"]), float(case["sigma"]), int(case["seed"]), progress=False)
    assert len(seeds) == int(library.episode.max()) + 1
    for name in ARRAYS:
        np.testing.assert_allclose(want[name], getattr(library, name), atol=1e-6, err_msg=name)


WRONG_ROLLOUTS = {
    "labels negated (the graders' wrong answer)": (("labels.append(label)", "labels.append(-label)"), "labels"),
    "no noise": (("env.step(label + rng.normal(0.0, sigma, 6))", "env.step(label)"), "noise"),
    "no expert.reset()": (("    expert.reset()\n", ""), "labels"),
    "going on after the episode ended": (("        if terminated or truncated:\n            break\n", ""), "states"),
}


@pytest.mark.parametrize("case", WRONG_ROLLOUTS)
def test_a_wrong_rollout_fails(case):
    (old, new), word = WRONG_ROLLOUTS[case]
    answer = changed(ANSWERS["ch03_noisy_rollout"], old, new)
    found = failures("ch03_noisy_rollout", _namespace(ch03_noisy_rollout=answer), 0)
    assert any(word in message for message in found), found


WRONG_DATA_SETS = {
    "last trajectory not cut": (("keep = min(len(joints), samples - n)", "keep = len(joints)"), "rows"),
    "a generator of its own per trajectory": (
        ("expert, rng, sigma,", "expert, np.random.default_rng(seed), sigma,"),
        "seeds",
    ),
    "time steps counted over the data set": (("np.arange(keep)))", "np.arange(n, n + keep)))"), "time steps"),
}


@pytest.mark.parametrize("case", WRONG_DATA_SETS)
def test_a_wrong_data_set_fails(case):
    (old, new), word = WRONG_DATA_SETS[case]
    answer = changed(ANSWERS["ch03_rollout_demos"], old, new)
    found = failures("ch03_rollout_demos", _namespace(ch03_rollout_demos=answer), 0)
    assert any(word in message for message in found), found


@pytest.mark.parametrize("exercise", ["ch03_noisy_rollout", "ch03_rollout_demos"])
def test_an_unsolved_stub_fails(exercise):
    found = failures(exercise, _namespace(**{exercise: stub(ANSWERS[exercise])}), 0)
    assert found == UNSOLVED
