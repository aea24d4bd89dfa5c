"""The trusted checks of chapter 06's eight exercises (vdtutorial/course/checks/ch06.py), run as the grader runs
them: the teacher's solutions (taken from 06a's and 06b's answer cells) pass on every seed; the classroom's
deliberately wrong answers, other plausible mistakes and an unsolved stub fail, with messages that give no number
away."""

import numpy as np
import pytest

from check_support import UNSOLVED, answers, executed, failures, stub
from vdtutorial.course import checks
from vdtutorial.course.checks import ch06

#: The answer cells' notebook, and the other answers the exercise's function calls (6.8 calls 6.7's search).
EXERCISES = {
    "ch06_reinforce": ("06a_trpo_pieces", ()),
    "ch06_surrogate": ("06a_trpo_pieces", ()),
    "ch06_conjugate_gradient": ("06a_trpo_pieces", ()),
    "ch06_fisher_vector_product": ("06a_trpo_pieces", ()),
    "ch06_gae": ("06a_trpo_pieces", ()),
    "ch06_linear_baseline": ("06b_trpo_assembled", ()),
    "ch06_line_search": ("06b_trpo_assembled", ()),
    "ch06_trpo_update": ("06b_trpo_assembled", ("ch06_line_search",)),
}
#: What the answer cells use from the chapter's first code cell.
CONTEXT = """
import math
import numpy as np
import torch
from torch.distributions import Normal, kl_divergence
from vdtutorial.trust_region import conjugate_gradient, double_backward_fvp, flat_grad, mean_kl, set_flat_params
"""
#: (exercise, text of the teacher's solution, the wrong version; or tuples of them, for a mistake made in several
#: places): the classroom's wrong answers first.
MISTAKES = [
    ("ch06_gae", "alive = 1.0 - dones[t]", "alive = 1.0"),
    ("ch06_line_search", "if kl <= config.max_kl and gain > 0:", "if kl <= config.max_kl:"),
    ("ch06_reinforce", "error ** 2 / variance - 1.0", "error ** 2 / variance"),
    ("ch06_reinforce", ".mean(axis=0)", ".sum(axis=0)"),
    (
        "ch06_surrogate",
        "log_pi(theta) - log_pi(torch.as_tensor(theta_old))",
        "log_pi(torch.as_tensor(theta_old)) - log_pi(theta)",
    ),
    ("ch06_surrogate", "ratio = torch.exp(log_pi(theta)", "ratio = 1 + (log_pi(theta)"),
    (
        "ch06_surrogate",
        "return (ratio * torch.as_tensor(advantages)).mean()",
        "return (ratio * torch.as_tensor(advantages)).mean().item()",
    ),
    (
        "ch06_surrogate",
        "ratio = torch.exp(log_pi(theta) - log_pi(torch.as_tensor(theta_old)))",
        "ratio = torch.exp(log_pi(theta) - log_pi(torch.as_tensor(theta_old))).detach()",
    ),
    ("ch06_conjugate_gradient", "p = r + (rr_new / rr) * p", "p = r"),
    (
        "ch06_conjugate_gradient",
        ("r, p = b.clone(), b.clone()", "r = r - step * Ap"),
        ("r, p = b, b.clone()", "r -= step * Ap"),
    ),
    ("ch06_conjugate_gradient", "step = rr / (p @ Ap)", "step = rr / (p @ p)"),
    ("ch06_fisher_vector_product", " + damping * v", ""),
    ("ch06_fisher_vector_product", ".sum(-1).mean()", ".sum()"),
    ("ch06_fisher_vector_product", "retain_graph=True", "retain_graph=False"),
    ("ch06_gae", "next_value = values[t]", "next_value = last_value"),
    ("ch06_gae", "gamma * lam * alive * next_adv", "gamma * alive * next_adv"),
    ("ch06_linear_baseline", "np.clip(features, -10.0, 10.0)", "np.asarray(features)"),
    ("ch06_linear_baseline", "dtype=np.float64).reshape(-1, 1) / 100.0", "dtype=np.float64).reshape(-1, 1)"),
    (
        "ch06_linear_baseline",
        "[f, f ** 2, t, t ** 2, t ** 3, np.ones_like(t)]",
        "[np.ones_like(t), f, f ** 2, t, t ** 2, t ** 3]",
    ),
    ("ch06_line_search", "fraction = config.backtrack_coeff ** i", "fraction = config.backtrack_coeff ** (i + 1)"),
    ("ch06_line_search", "2 * config.max_kl", "config.max_kl"),
    ("ch06_line_search", "        set_flat_params(params, theta_old)\n    return None", "    return None"),
    ("ch06_trpo_update", "mean_kl(old, dist)", "mean_kl(dist, old)"),
    ("ch06_trpo_update", "direction = conjugate_gradient(Fvp, g, config.cg_iters)", "direction = g"),
    ("ch06_trpo_update", '"entropy": old.entropy()', '"entropy": policy.distribution(obs).entropy()'),
    ("ch06_trpo_update", '"rejected" if fraction is None else fraction', "None if fraction is None else fraction"),
]


ANSWERS = {
    grade_id: source
    for notebook in sorted({notebook for notebook, _ in EXERCISES.values()})
    for grade_id, source in answers(notebook).items()
}


def namespace(exercise: str, change: tuple | None = None, unsolved: bool = False) -> dict:
    """The notebook's namespace after the answer cells of ``exercise`` (and those it calls) ran: the teacher's
    solution, with ``change`` = (text, replacement) made in it (or tuples of texts and replacements), or an
    unsolved stub."""
    source = ANSWERS[exercise]
    if change is not None:
        texts, wrongs = change if isinstance(change[0], tuple) else ((change[0],), (change[1],))
        for text, wrong in zip(texts, wrongs):
            assert source.count(text) == 1, text
            source = source.replace(text, wrong)
    if unsolved:
        source = stub(source)
    return executed({}, CONTEXT, *(ANSWERS[other] for other in EXERCISES[exercise][1]), source)


def test_every_exercise_of_the_two_notebooks_has_a_check_in_order():
    assert [item.exercise for item in ch06.CHECKS] == list(EXERCISES)
    assert set(EXERCISES) <= set(ANSWERS)


@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_the_teachers_solution_passes(exercise):
    names = namespace(exercise)
    for seed in range(6):
        assert failures(exercise, names, seed) == [], seed


@pytest.mark.parametrize("exercise, text, wrong", MISTAKES, ids=[f"{m[0]}-{k}" for k, m in enumerate(MISTAKES)])
def test_a_mistake_fails(exercise, text, wrong):
    names = namespace(exercise, (text, wrong))
    for seed in range(3):
        assert failures(exercise, names, seed), seed  # and no message gives a number away


def test_a_wrong_line_search_costs_its_own_exercise_only():
    """6.8's update calls the student's 6.7 line search. Whether a wrong search (one that accepts a step that lowers
    the surrogate) also spoils an update depended on the drawn batches, so a class's points for 6.8 depended on the
    draw (about one draw in eleven); the update's check runs it with the library's search, and the wrong search costs
    6.7 alone."""
    search = ANSWERS["ch06_line_search"].replace("if kl <= config.max_kl and gain > 0:", "if kl <= config.max_kl:")
    wrong = executed({}, CONTEXT, search, ANSWERS["ch06_trpo_update"])  # one namespace, as the kernel's globals
    # seeds whose batches led the wrong search to accept a step that lowers the surrogate, so that the update failed
    # before the check used the library's search (13 of seeds 0-149 did, these among them)
    for seed in (21, 29, 30, 42, 77, 80):
        assert failures("ch06_trpo_update", wrong, seed) == [], seed
    assert failures("ch06_line_search", wrong, 0)
    assert wrong["my_line_search"].__name__ == "my_line_search"  # the student's search is put back


@pytest.mark.parametrize("exercise", list(EXERCISES))
def test_an_unsolved_stub_fails(exercise):
    assert failures(exercise, namespace(exercise, unsolved=True), 0) == UNSOLVED


def test_the_inputs_are_plain_and_fresh_for_each_seed():
    for item in ch06.CHECKS:
        first, again, other = (checks.plain(item.inputs(np.random.default_rng(seed))) for seed in (0, 0, 1))
        assert first.keys() == again.keys() and all(np.array_equal(first[k], again[k]) for k in first), item.exercise
        assert any(not np.array_equal(first[k], other[k]) for k in first), item.exercise


def test_the_line_search_problems_cover_every_outcome():
    """Each seed's problems include a full step accepted, a backtracked one and a rejection; the updates include
    a backtracked step and a rejected one."""
    names = namespace("ch06_line_search")
    for seed in range(20):
        item = checks.check("ch06_line_search")
        outputs = checks.nested(checks._probe(item, names, checks.plain(item.inputs(np.random.default_rng(seed)))))
        outcomes = {
            "rejected" if out["rejected"] else "full" if out["fraction"] == 1 else "backtracked"
            for out in outputs.values()
        }
        assert outcomes == {"rejected", "full", "backtracked"}, seed
    names = namespace("ch06_trpo_update")
    item = checks.check("ch06_trpo_update")
    outputs = checks.nested(checks._probe(item, names, checks.plain(item.inputs(np.random.default_rng(0)))))
    assert outputs["case4"]["rejected"] and outputs["case3"]["fraction"] < 1


#: Two slips of 6.8 whose numbers alone (a line-search fraction, a mean KL a little off) do not say what is wrong,
#: with the words the check must name them by: (text of the teacher's solution, the slip, words of the message).
NAMED_SLIPS = {
    "surrogate's sign": (
        "return (ratio * advantages).mean(), mean_kl(old, dist)",
        "return -(ratio * advantages).mean(), mean_kl(old, dist)",
        "the sign of your surrogate",
    ),
    "ratio inverted": (
        "ratio = torch.exp(dist.log_prob(actions).sum(-1) - old_log_prob)",
        "ratio = torch.exp(old_log_prob - dist.log_prob(actions).sum(-1))",
        "the sign of your surrogate",
    ),
    "no damping": (
        "double_backward_fvp(policy, params, obs, old, config.cg_damping)",
        "double_backward_fvp(policy, params, obs, old, 0.0)",
        "without damping",
    ),
}


@pytest.mark.parametrize("slip", sorted(NAMED_SLIPS))
def test_the_update_check_names_the_slip(slip):
    """The check says which slip the update made, for every batch whose step was accepted, and says it in words."""
    text, wrong, words = NAMED_SLIPS[slip]
    names = namespace("ch06_trpo_update", (text, wrong))
    for seed in range(3):
        found = failures("ch06_trpo_update", names, seed)
        named = [failure for failure in found if words in failure]
        assert len(named) >= 3 and all("mean KL" not in failure for failure in found), (seed, found)


def test_a_right_update_is_named_no_slip():
    names = namespace("ch06_trpo_update")
    item = checks.check("ch06_trpo_update")
    inputs = item.inputs(np.random.default_rng(0))
    outputs = checks.nested(checks._probe(item, names, checks.plain(inputs)))
    cases = checks.nested(checks.plain(inputs))
    assert [
        ch06._named_slip(cases[key], outputs[key], ch06._library_update(cases[key], ch06._update_config(cases[key]))[1])
        for key in sorted(cases)
        if key.startswith("case")
    ] == [None] * 5
