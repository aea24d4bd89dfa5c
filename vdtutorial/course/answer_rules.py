"""What an answer cell may not do: the grader's static check of a submission's own code, before any of it runs.

An exercise asks a student to build a piece the library holds, and its hidden tests compare the two: calling the
library's piece, or changing what the tests run, would score without solving anything. :func:`answer_violations`
reads a cell of the student's code and names each of these, in words a teacher can check:

* **a forbidden name**: the library functions and classes that an exercise rebuilds (:data:`FORBIDDEN`, per
  exercise), imported, used (unless the answer defines a name of its own that way) or written as a string;
* **code reached by a string, or the kernel**: ``exec``, ``eval``, ``compile``, ``__import__``, ``globals()``,
  ``vars()``, ``locals()``, ``getattr``/``setattr``/``delattr`` whose name is not a plain string, ``sys.modules``,
  ``__dict__``, ``__class__``, ``type(obj)``, importing ``importlib``, ``inspect``, ``gc``, ``builtins``, ``ctypes``
  or the grader's own ``vdtutorial.course``; ``get_ipython``, ``showtraceback``,
  ``exit``/``quit``/``sys.exit``/``os._exit``/``os.kill``;
* **changing what it did not create**: assigning to an attribute or an item of a name the cell did not bind to a
  value it made (``torch.testing.assert_close = ...``, ``t = np.testing; t.assert_allclose = ...``, a chapter's
  object, the library), or deleting one;
* **objects that compare as anything**: a class defining ``__eq__``, ``__ne__``, ``__bool__``, ``__array__``,
  ``__array_ufunc__``, ``__array_function__``, ``__torch_function__`` or ``__torch_dispatch__``.

A forbidden name costs that exercise its points; anything else costs the whole notebook, whose tests it could
change (:func:`vdtutorial.course.classroom.refusals`). The teacher's solutions pass the check (a test runs it on
every exercise), so none of it is needed to solve an exercise. A static check cannot see what code does at run
time: it is the grader's first defence, not its last (see "What the grader guarantees" in notebooks/TEACHING.md).

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import ast
import re
from typing import NamedTuple

#: Per exercise (its answer cell's nbgrader ``grade_id``, in the order of the chapters): the library's names for what
#: the student builds, the pieces its tests compare with or that would do the exercise in one call. Not the helpers the
#: teacher's solution itself calls (``reach_goal``, ``solve_ik``, ``model_kl``, ``flat_grad`` in 06a's Fisher product,
#: ``set_flat_params``, ``svdo_layers``, ...), and no name that ordinary code would write: a method with a generic
#: name (``step``, ``kl``, ``update``) is forbidden through its class or its module-level function. A name is also
#: looked for in a string that is nothing but the name (``"holm_rejections"``, a dotted path ending in it).
FORBIDDEN: dict[str, tuple[str, ...]] = {
    # 01: the reaching env's own goal test and reward (eq. 11), which its step computes
    "ch01_reward_eq11": ("JacoReachEnv", "_goal_status", "_reward"),
    # 01: the library's episode runners that count how episodes end
    "ch01_collision_share": ("successes_per_episode", "expert_success_rate"),
    # 01: the grasping env's own goal test, reward and tilt of the approach axis
    "ch01_grasp_reward": ("JacoGraspEnv", "_goal_status", "_reward", "tilt_deg"),
    # 02: the goal set G of eq. 9
    "ch02_goal_set": ("solution_set",),
    # 02: eq. 9 with wrap-around joints, and its per-candidate shift
    "ch02_nearest_goal": ("nearest_goal", "nearest_equivalent"),
    # 02: eq. 10 with the overshoot fix
    "ch02_step_towards": ("step_towards",),
    # 03: the data set generator that runs the noisy rollouts of eqs. 5-8
    "ch03_noisy_rollout": ("generate_demos",),
    # 03: the data set D of eq. 8 (generate_demos, and collect, its rollout loop with the executed action open)
    "ch03_rollout_demos": ("generate_demos", "collect"),
    # 04: the sparse VD layers' shared base class, whose forward pass samples the weights' noise
    "ch04_gaussian_dropout": ("SVDOLayer",),
    # 04: the sparse VD layers, their shared base class, their factories and the KL approximation
    "ch04_svdo_layer": ("LinearSVDO", "SVDOLayer", "Conv2dSVDO", "make_linear", "make_conv2d", "kl_approx"),
    # 04: compaction of a pruned network, its pieces and the dead-unit finder
    "ch04_compact": ("compact", "compact_layers", "rebuild_sequential", "dead_units"),
    # 05: the library's pre-training (its loop holds the ELBO step), plain and with a fitted sigma
    "ch05_elbo_step": ("pretrain", "pretrain_with_sigma"),
    # 05: the library's pre-training loop with the beta warm-up
    "ch05_clone_vd": ("pretrain", "pretrain_with_sigma"),
    # 06a: the library's gradient of a scalar as one vector (autograd, which the exercise replaces by hand)
    "ch06_reinforce": ("flat_grad",),
    # 06a: TRPO's step, which holds the library's importance-sampled surrogate
    "ch06_surrogate": ("_trpo_step",),
    # 06a: conjugate gradient
    "ch06_conjugate_gradient": ("conjugate_gradient",),
    # 06a: the Fisher-vector products: double backward, its inner product, and the fast Gauss-Newton form
    "ch06_fisher_vector_product": (
        "double_backward_fvp",
        "fisher_vector_product",
        "gauss_newton_fvp",
        "GaussNewtonFisher",
    ),
    # 06a: generalised advantage estimation, and the batch function that calls it
    "ch06_gae": ("gae", "advantages_and_returns"),
    # 06b: rllab's linear feature baseline (its design matrix and ridge fit)
    "ch06_linear_baseline": ("LinearFeatureBaseline",),
    # 06b: the backtracking line search
    "ch06_line_search": ("line_search",),
    # 06b: TRPO's own steps 3-6 (not line_search: the statistics' key "line_search" is a string the answer writes)
    "ch06_trpo_update": ("_trpo_step",),
    # 07: the library's pruning (layer and policy method, model function) and its kept-weight masks
    "ch07_prune": ("prune_", "prune_model", "keep_mask", "kept_weights"),
    # 07: the figures' smoothed curves over seeds and their first crossing of a level
    "ch07_steps_to_level": ("curves_from_rows", "steps_to_reach", "_first_reach"),
    # 08: the grasping env's own goal test and tilt of the approach axis
    "ch08_grasp_success": ("JacoGraspEnv", "_goal_status", "tilt_deg"),
    # 08: the library's episode runner that counts outcomes and sums rewards
    "ch08_trajectory_return": ("successes_per_episode",),
    # 09: DART's noise estimate (from the policy's errors) and its noisy behaviour
    "ch09_dart_noise": ("estimate_noise", "noise_estimate", "policy_errors", "noisy_expert"),
    # 09: DAgger's per-step mixture of expert and learner
    "ch09_dagger_plan": ("mixture",),
    # 10: Welch's interval and the statistics under it
    "ch10_welch_verdict": ("welch_interval", "_welch"),
    # 10: Holm's step-down procedure
    "ch10_holm": ("holm_rejections",),
    # 11: the L2 entry, whose penalty is the numerator of the matched strength
    "ch11_l1_strength": ("WeightDecay",),
    # 11: the L2 entry: an L1 entry is written beside it, not built on its penalty
    "ch11_l1_penalty": ("WeightDecay",),
}

#: What reaches code through a string, the kernel or the grader's machinery: builtins called by their plain name
#: (``policy.eval()`` and ``re.compile`` are methods, not these) ...
_ESCAPE_NAMES = {
    "exec",
    "eval",
    "compile",
    "__import__",
    "globals",
    "vars",
    "locals",
    "exit",
    "quit",
    "breakpoint",
    "get_ipython",
    "importlib",
    "inspect",
    "builtins",
    "__builtins__",
}
#: ... attributes of any object ...
_ESCAPE_ATTRIBUTES = {
    "__dict__",
    "__globals__",
    "__code__",
    "__closure__",
    "__subclasses__",
    "__class__",
    "__wrapped__",
    "__builtins__",
    "_exit",
    "showtraceback",
    "_showtraceback",
}
#: ... attributes of these modules (``sys.modules``, ``sys.exit``, ``os.kill``) ...
_ESCAPE_MODULE_ATTRIBUTES = {"sys": {"modules", "exit", "settrace", "setprofile"}, "os": {"kill", "killpg", "abort"}}
#: ... and modules an answer may not import.
_ESCAPE_MODULES = {
    "importlib",
    "inspect",
    "gc",
    "builtins",
    "ctypes",
    "signal",
    "IPython",
    "ipykernel",
    "nbgrader",
    "nbformat",
    "nbclient",
    "jupyter_client",
}
#: ... nor the grader's own package (its checks, its sandbox).
_GRADER = "vdtutorial.course"


def _grader_module(dotted: str) -> set[str]:
    return {_GRADER} if dotted == _GRADER or dotted.startswith(_GRADER + ".") else set()


#: The attribute functions, allowed only with a plain string for the name.
_ATTRIBUTE_CALLS = {"getattr", "setattr", "delattr", "hasattr"}
#: Special methods that make an object compare or convert as it likes.
_COMPARISON_HOOKS = {
    "__eq__",
    "__ne__",
    "__bool__",
    "__array__",
    "__array_ufunc__",
    "__array_function__",
    "__torch_function__",
    "__torch_dispatch__",
}


def _is_alias(value: ast.AST | None, created: set[str]) -> bool:
    """Whether binding a name to ``value`` only gives another name to something the cell did not create: a name,
    an attribute or an item of one (``t = torch.testing``), or a literal collection holding such."""
    if isinstance(value, (ast.List, ast.Tuple, ast.Set)):
        return any(_is_alias(item, created) for item in value.elts)
    return isinstance(value, (ast.Name, ast.Attribute, ast.Subscript, ast.Starred)) and _root(value) not in created


def _target_names(target: ast.AST | None) -> set[str]:
    """The plain names an assignment target binds (``a``, ``a, (b, *c)``), not the roots of ``a.x`` or ``a[0]``."""
    if isinstance(target, ast.Name):
        return {target.id}
    if isinstance(target, (ast.Tuple, ast.List)):
        return {name for item in target.elts for name in _target_names(item)}
    if isinstance(target, ast.Starred):
        return _target_names(target.value)
    return set()


def _created_names(tree: ast.AST) -> set[str]:
    """The names the cell binds to what it made itself: its functions and classes and their parameters,
    exception names, and names bound to a new value (a call's result, a literal, an expression). A name bound to
    an existing object (an import, ``t = torch.testing``, a loop over a module list) is an alias, not a creation."""
    created = set()
    for _ in range(3):  # aliases of aliases: a few passes reach a fixed point in practice
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                created.add(node.name)
            elif isinstance(node, ast.arg):
                created.add(node.arg)
            elif isinstance(node, ast.ExceptHandler) and node.name:
                created.add(node.name)
            elif isinstance(
                node,
                (
                    ast.Assign,
                    ast.AnnAssign,
                    ast.AugAssign,
                    ast.NamedExpr,
                    ast.For,
                    ast.AsyncFor,
                    ast.comprehension,
                    ast.withitem,
                ),
            ):
                value = (
                    node.iter
                    if isinstance(node, (ast.For, ast.AsyncFor, ast.comprehension))
                    else node.context_expr
                    if isinstance(node, ast.withitem)
                    else node.value
                )
                targets = (
                    node.targets
                    if isinstance(node, ast.Assign)
                    else [node.optional_vars]
                    if isinstance(node, ast.withitem)
                    else [node.target]
                )
                if not _is_alias(value, created):
                    created |= {name for target in targets for name in _target_names(target)}
    return created


def _root(node: ast.AST) -> str | None:
    """The name an attribute or item chain starts from (``torch`` in ``torch.testing.assert_close``)."""
    while isinstance(node, (ast.Attribute, ast.Subscript, ast.Call)):
        node = node.func if isinstance(node, ast.Call) else node.value
    return node.id if isinstance(node, ast.Name) else None


def _forbidden_uses(node: ast.AST, forbidden: set[str], created: set[str]) -> set[str]:
    """The forbidden names a node reaches: a name the cell did not define itself, an attribute of something it did
    not create, an imported name, or a string that is just the name (``"LinearSVDO"``,
    ``"vdtutorial.vd.kl_approx"``)."""
    if isinstance(node, ast.Name) and node.id not in created:
        return {node.id} & forbidden
    if isinstance(node, ast.Attribute) and _root(node) not in created:
        return {node.attr} & forbidden
    if isinstance(node, ast.alias):
        return set(node.name.split(".")) & forbidden
    if isinstance(node, ast.Constant) and isinstance(node.value, str) and re.fullmatch(r"[\w.]+", node.value.strip()):
        return set(node.value.strip().split(".")) & forbidden
    return set()


def _escapes(node: ast.AST) -> set[str]:
    """What of the escape hatches (:data:`_ESCAPE_NAMES` and the others) a node uses."""
    if isinstance(node, ast.Name):
        return {node.id} & _ESCAPE_NAMES
    if isinstance(node, ast.Attribute):
        module = node.value.id if isinstance(node.value, ast.Name) else None
        return ({node.attr} & (_ESCAPE_ATTRIBUTES | _ESCAPE_MODULE_ATTRIBUTES.get(module, set()))) | (
            {module} & _ESCAPE_MODULES
        )
    if isinstance(node, ast.alias):
        return {node.name.split(".")[0], *_grader_module(node.name)} & (_ESCAPE_MODULES | {_GRADER})
    if isinstance(node, ast.ImportFrom) and node.module:
        return {node.module.split(".")[0], *_grader_module(node.module)} & (_ESCAPE_MODULES | {_GRADER})
    return set()


class Violation(NamedTuple):
    """One thing an answer cell may not do: ``kind`` is ``"forbidden"`` (it uses the library's piece ``name`` that
    the exercise rebuilds: that exercise scores 0) or ``"tampering"`` (it could change what any test of the
    notebook does: every exercise of the notebook scores 0); ``text`` says what, for the teacher."""

    kind: str
    line: int
    text: str
    name: str = ""  # the forbidden name, for a "forbidden" violation

    def __str__(self) -> str:
        return f"line {self.line}: {self.text}"


def answer_violations(source: str, forbidden: tuple[str, ...] = ()) -> list[Violation]:
    """What the cell ``source`` does that the student's code may not (the four kinds above), in the order found;
    empty when it is clean. ``forbidden``: the exercise's names from :data:`FORBIDDEN`. Code that does not parse
    is left to the kernel (it fails there, and scores nothing)."""
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return []
    found = []

    def say(kind: str, line: int, text: str, name: str = "") -> None:
        if (violation := Violation(kind, line, text, name)) not in found:
            found.append(violation)

    created = _created_names(tree)
    for node in ast.walk(tree):
        line = getattr(node, "lineno", 0)
        for name in sorted(_forbidden_uses(node, set(forbidden), created)):
            how = "writes the library's {} in a string" if isinstance(node, ast.Constant) else "uses the library's {}"
            say("forbidden", line, how.format(name) + ", which this exercise rebuilds", name)
        for name in sorted(_escapes(node)):
            say("tampering", line, f"uses {name}, which reaches code or the kernel outside the answer")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            if node.func.id in _ATTRIBUTE_CALLS:
                name = node.args[1] if len(node.args) > 1 else None
                if not (isinstance(name, ast.Constant) and isinstance(name.value, str)):
                    say("tampering", line, f"calls {node.func.id} with a name that is not a plain string")
                elif node.func.id in ("setattr", "delattr") and _root(node.args[0]) not in created:
                    say(
                        "tampering",
                        line,
                        f"changes {_root(node.args[0]) or 'an object'}.{name.value}, which the answer did not create",
                    )
            elif node.func.id == "type" and len(node.args) == 1:
                say("tampering", line, "takes the class of an object with type(...), which can reach the library's")
        targets = (
            node.targets
            if isinstance(node, (ast.Assign, ast.Delete))
            else [node.target]
            if isinstance(node, (ast.AugAssign, ast.AnnAssign))
            else []
        )
        for target in targets:
            if isinstance(target, (ast.Attribute, ast.Subscript)) and _root(target) not in created:
                say("tampering", line, f"changes {ast.unparse(target)}, which the answer did not create")
        if isinstance(node, ast.ClassDef):
            hooks = {item.name for item in node.body if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef))}
            for hook in sorted(hooks & _COMPARISON_HOOKS):
                say("tampering", line, f"defines {node.name}.{hook}, which would let a result compare as anything")
    return found
