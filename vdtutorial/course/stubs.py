"""The library as a graded kernel sees it: the pieces a chapter's exercises rebuild replaced by stubs.

A student's answer must not score by handing the library's implementation back as their own. Reading the answer's
code for the names it uses (:mod:`vdtutorial.course.answer_rules`) catches the honest mistake early, but code can
reach an object by routes no reading sees: a name built from strings (``pkgutil.resolve_name``), ``sys.modules``,
``importlib``, ``runpy``, ``pickle`` of a global reference, code decoded at run time, an import in another
exercise's cell. Each of these only looks the object up; so the grader removes the object instead. The kernel
that runs a chapter imports a copy of the package (:func:`stubbed_copy`) in which every piece of :data:`STUBS`
for the chapter's exercises keeps its name and signature, but its body is one ``raise`` of
:class:`NotImplementedError` saying which exercise asks for it (:func:`message`). The copy is shown to the kernel
at the package's own path, so that every route to the package ends there; the original source never enters the
sandbox, and the stubbed code never ran, so no object holding it exists to be found.

A piece that a later exercise of the same chapter is given (4.3 compacts a network of the library's
``LinearSVDO`` layers, and so needs their parameters, ``log_alpha``, ``keep_mask`` and eval mode's forward pass)
keeps those parts (:data:`KEPT`): only what scores the earlier exercise is stubbed (training mode's sampling and
the KL). Where a later exercise's check needs what a stubbed piece computes, the grader computes it and hands it
over with the exercise's inputs instead: the environments' goal tests are stubs in chapters 01 and 08, so the
episode runners of 1.2 and 8.2 are given the grader's own episodes, played back in the kernel
(:class:`vdtutorial.course.checks.ch01.Replay`). A stub that an answer called is named
in the grader's table (:func:`called`), so that the teacher sees why the exercise scored nothing.

The trusted checks' probes run in the kernel next to the student's code and can reach only what it can: they call
the student's functions on the grader's inputs, and every reference answer is computed in the grader's own
process, from the unstubbed library (:mod:`vdtutorial.course.checks`).

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import ast
import importlib.util
import re
import shutil
from pathlib import Path

#: Per exercise (its answer cell's ``grade_id``): the library's pieces the grading kernel's copy stubs, as
#: ``module:qualname`` (a method as ``module:Class.method``, a class as a whole by its name). The pieces are those
#: of :data:`vdtutorial.course.answer_rules.FORBIDDEN` that compute what the exercise's check compares, and every
#: other implementation of the same computation in the package; not the helpers the teacher's solution calls
#: (``flat_grad``, ``mean_kl``, ``set_flat_params``), which compute nothing the check compares.
STUBS: dict[str, tuple[str, ...]] = {
    # 01: the reaching env's goal test and eq. 11 (its step, reset and every runner on it stop there)
    "ch01_reward_eq11": (
        "vdtutorial.envs.reach:JacoReachEnv._goal_status",
        "vdtutorial.envs.reach:JacoReachEnv._reward",
    ),
    # 01: the library's episode runners that count how episodes end, and the check's own count of how the given
    # episodes ended (its verdict's helper, which the kernel must not lend out)
    "ch01_collision_share": (
        "vdtutorial.experiments.evaluation:successes_per_episode",
        "vdtutorial.experiments.evaluation:expert_success_rate",
        "vdtutorial.course.checks.ch01:runner_reference",
    ),
    # 01: the grasping env's goal test, its reward and the tilt of the approach axis the test rests on
    "ch01_grasp_reward": (
        "vdtutorial.envs.grasp:JacoGraspEnv._goal_status",
        "vdtutorial.envs.grasp:JacoGraspEnv._reward",
        "vdtutorial.envs.grasp:tilt_deg",
    ),
    # 02: the goal set G (IKExpert.reset builds it with this, so the library's expert stops here in chapter 02)
    "ch02_goal_set": ("vdtutorial.expert:solution_set",),
    # 02: eq. 9 and its per-candidate shift to the nearest equivalent angles (IKExpert.goal computes through it)
    "ch02_nearest_goal": ("vdtutorial.expert:nearest_goal", "vdtutorial.expert:nearest_equivalent"),
    # 02: eq. 10 with the overshoot fix (IKExpert.action computes through it)
    "ch02_step_towards": ("vdtutorial.expert:step_towards",),
    # 03: the rollout loop of eqs. 5-8 with the executed action open: one noisy rollout is its inner loop
    "ch03_noisy_rollout": ("vdtutorial.demos:collect",),
    # 03: the data set D: the noisy expert's rollouts (generate_demos), the loop they run in (collect), and the
    # check's own assembly of D from given trajectories (its verdict's helper, which the kernel must not lend out)
    "ch03_rollout_demos": (
        "vdtutorial.demos:generate_demos",
        "vdtutorial.demos:collect",
        "vdtutorial.course.checks.ch03:_expected",
    ),
    # 04: eq. 4's noisy forward pass (the sparse VD layers' shared forward)
    "ch04_gaussian_dropout": ("vdtutorial.vd:SVDOLayer.forward",),
    # 04: the layer: its forward pass and its KL (log alpha and keep_mask stay: 4.3 is given library layers)
    "ch04_svdo_layer": ("vdtutorial.vd:SVDOLayer.forward", "vdtutorial.vd:SVDOLayer.kl", "vdtutorial.vd:kl_approx"),
    # 04: compaction and the dead-unit finder it rests on
    "ch04_compact": (
        "vdtutorial.analysis.compact:compact",
        "vdtutorial.analysis.compact:compact_layers",
        "vdtutorial.analysis.compact:rebuild_sequential",
        "vdtutorial.analysis.sparsity:dead_units",
    ),
    # 05: the library's cloning loop holds the ELBO step; the VD method's penalty is its beta-weighted KL / N with
    # the warm-up; the sigma-fitting variant runs the same loop
    "ch05_elbo_step": (
        "vdtutorial.pretrain:pretrain",
        "vdtutorial.experiments.initial_sigma:pretrain_with_sigma",
        "vdtutorial.methods:SparseVD.penalty",
    ),
    "ch05_clone_vd": (
        "vdtutorial.pretrain:pretrain",
        "vdtutorial.experiments.initial_sigma:pretrain_with_sigma",
        "vdtutorial.methods:SparseVD.penalty",
    ),
    # 06a: the surrogate is computed inside TRPO's step
    "ch06_surrogate": ("vdtutorial.trpo:TRPO._trpo_step",),
    "ch06_conjugate_gradient": ("vdtutorial.trust_region:conjugate_gradient",),
    # 06a: every Fisher-vector product of the package: double backward, its inner product, the Gauss-Newton form
    "ch06_fisher_vector_product": (
        "vdtutorial.trust_region:double_backward_fvp",
        "vdtutorial.trust_region:fisher_vector_product",
        "vdtutorial.fast.fisher:GaussNewtonFisher",
        "vdtutorial.fast.fisher:gauss_newton_fvp",
    ),
    "ch06_gae": ("vdtutorial.trpo:gae", "vdtutorial.trpo:advantages_and_returns"),
    # 06b
    "ch06_linear_baseline": ("vdtutorial.baselines:LinearFeatureBaseline",),
    "ch06_line_search": ("vdtutorial.trust_region:line_search",),
    "ch06_trpo_update": ("vdtutorial.trpo:TRPO._trpo_step",),
    # 07: pruning (the layer's and the policy's method, the model function) and the masks it freezes (the layer's
    # own, and the analysis' for any layer)
    "ch07_prune": (
        "vdtutorial.vd:SVDOLayer.prune_",
        "vdtutorial.policy:GaussianPolicy.prune_",
        "vdtutorial.vd:prune_model",
        "vdtutorial.vd:SVDOLayer.keep_mask",
        "vdtutorial.analysis.sparsity:kept_weights",
    ),
    # 07: the figures' smoothed curves over seeds, and both first crossings of a level (the claims' own too)
    "ch07_steps_to_level": (
        "vdtutorial.experiments.curves:curves_from_rows",
        "vdtutorial.experiments.curves:steps_to_reach",
        "vdtutorial.experiments.effects:_first_reach",
    ),
    # 08: the grasping env's goal test and the tilt it rests on (8.2's runner gets the grader's trajectories played
    # back, vdtutorial/course/checks/ch01.py's Replay)
    "ch08_grasp_success": ("vdtutorial.envs.grasp:JacoGraspEnv._goal_status", "vdtutorial.envs.grasp:tilt_deg"),
    # 08: the library's episode runner that counts outcomes and sums rewards
    "ch08_trajectory_return": ("vdtutorial.experiments.evaluation:successes_per_episode",),
    # 09: DART's Sigma_hat (the errors, their mean outer product, the two on the held-out split) and its behaviour
    "ch09_dart_noise": (
        "vdtutorial.beyond.dart:estimate_noise",
        "vdtutorial.beyond.dart:noise_estimate",
        "vdtutorial.beyond.dart:policy_errors",
        "vdtutorial.beyond.dart:noisy_expert",
    ),
    # 09: DAgger's per-step mixture of expert and learner
    "ch09_dagger_plan": ("vdtutorial.beyond.dagger:mixture",),
    # 10: Welch's interval, the statistics under it, and the reading of an interval as a verdict
    "ch10_welch_verdict": (
        "vdtutorial.experiments.effects:welch_interval",
        "vdtutorial.experiments.effects:_welch",
        "vdtutorial.experiments.effects:verdict",
    ),
    "ch10_holm": ("vdtutorial.experiments.effects:holm_rejections",),
    # 11: the L2 entry's penalty, l2 * sum W^2: the numerator of 11.1's matched strength, and the term 11.2 writes
    # beside it (the class stays: only its penalty computes what the checks compare)
    "ch11_l1_strength": ("vdtutorial.methods:WeightDecay.penalty",),
    "ch11_l1_penalty": ("vdtutorial.methods:WeightDecay.penalty",),
}

#: What a stub still does before it raises, where a later exercise or the chapter is given part of the piece: the
#: sparse VD layers' deterministic forward pass (eval mode, or a pruned layer) stays, since 4.3 compacts networks of
#: library layers and may run them; the sampling of training mode is what 4.1 and 4.2 build. A kernel stubs one
#: chapter's exercises, so the entries of different chapters never meet (the mask from log alpha is stubbed in
#: chapter 07's kernel only, where a layer's forward pass works once the answer has pruned it).
KEPT: dict[str, str] = {
    "vdtutorial.vd:SVDOLayer.forward": (
        "if self.pruned or not self.training:\n    return self._op(x, self.weight * self.keep_mask(), self.bias)"
    ),
    # 07: a pruned layer's mask is the one the answer froze, and its forward pass reads it (7.1's check runs the
    # student's pruned copy); the mask from log alpha, what 7.1 builds, is stubbed
    "vdtutorial.vd:SVDOLayer.keep_mask": "if self.pruned:\n    return self.mask",
}

#: Per exercise: the names of :data:`vdtutorial.course.answer_rules.FORBIDDEN` that are not pieces of its
#: :data:`STUBS` themselves but compute only through one of them (a subclass or a factory of a stubbed class), and
#: that piece.
THROUGH: dict[str, dict[str, str]] = {
    "ch03_noisy_rollout": {"generate_demos": "vdtutorial.demos:collect"},
    "ch04_svdo_layer": {
        "LinearSVDO": "vdtutorial.vd:SVDOLayer.forward",
        "Conv2dSVDO": "vdtutorial.vd:SVDOLayer.forward",
        "make_linear": "vdtutorial.vd:SVDOLayer.forward",
        "make_conv2d": "vdtutorial.vd:SVDOLayer.forward",
    },
}

#: Per exercise: the names of :data:`vdtutorial.course.answer_rules.FORBIDDEN` that the grading kernel keeps
#: working, and why: the chapter's later exercise, its probe or its own code needs the library's piece. For these
#: the static check alone keeps the piece out of the answer (notebooks/TEACHING.md lists them).
GIVEN: dict[str, dict[str, str]] = {
    "ch06_reinforce": {"flat_grad": "the Fisher-vector product exercise of the same chapter is built on it"},
}

#: The stub's words; :func:`called` reads them back.
_MESSAGE = "the library's {name} is stubbed in grading: it is what exercise {exercise} asks you to build"
_CALLED = re.compile(r"the library's ([\w.]+) is stubbed in grading: it is what exercise (\w+) asks you to build")


def message(name: str, exercise: str) -> str:
    """What the stub of ``name`` (``module:qualname``) raises: one line naming the exercise that rebuilds it."""
    return _MESSAGE.format(name=name.replace(":", "."), exercise=exercise)


def called(text: str) -> str | None:
    """The stub's line in ``text`` (an exception's message): the kernel can write any text, so a line is believed
    only if it is one the grader's own table would write for the exercise it names."""
    match = _CALLED.search(text or "")
    if match is None:
        return None
    try:
        pieces = targets([match.group(2)])
    except (OSError, SyntaxError):  # no such chapter: a line the grader never wrote
        return None
    known = {
        message(f"{module}:{name}", exercise) for module, named in pieces.items() for name, exercise in named.items()
    }
    return match.group(0) if match.group(0) in known else None


def verdicts(chapter: str, package: Path | None = None) -> dict[str, str]:
    """The verdict functions of the trusted checks of ``chapter`` (``"ch04"``), by exercise, read from the list
    ``CHECKS`` of its module without importing it. A verdict recomputes the answer in the grader's process: in the
    kernel, where only the probes run, it would be one more reference implementation to call, so it is stubbed too."""
    path = module_file(package or package_dir(), f"vdtutorial.course.checks.{chapter}")
    found = {}
    for node in ast.walk(ast.parse(path.read_text())):
        is_check = isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "Check"
        if is_check and len(node.args) == 4 and isinstance(node.args[0], ast.Constant):
            found[node.args[0].value] = node.args[3].id
    return found


def targets(exercises) -> dict[str, dict[str, str]]:
    """The stubs of ``exercises``, by module: ``{module: {qualname: exercise}}`` (the first exercise that names a
    piece is the one its message names): their pieces of :data:`STUBS`, and their checks' verdicts."""
    found: dict[str, dict[str, str]] = {}
    for exercise in exercises:
        for name in STUBS.get(exercise, ()):
            module, qualname = name.split(":")
            found.setdefault(module, {}).setdefault(qualname, exercise)
        chapter = exercise.split("_")[0]
        if exercise in (judged := verdicts(chapter)):
            found.setdefault(f"vdtutorial.course.checks.{chapter}", {})[judged[exercise]] = exercise
    return found


def _raise(name: str, exercise: str) -> list[ast.stmt]:
    kept = ast.parse(KEPT.get(name, "")).body
    return kept + [ast.parse(f"raise NotImplementedError({message(name, exercise)!r})").body[0]]


def stub_source(source: str, module: str, pieces: dict[str, str]) -> str:
    """``source`` (the module ``module``) with each piece of ``pieces`` (``{qualname: exercise}``) stubbed: a
    function's or method's body becomes the stub's ``raise``, after what :data:`KEPT` keeps of it (its signature
    and decorators stay); a class keeps its
    name and bases, and its body becomes an ``__init__`` that raises. ``KeyError`` for a piece not found, so that
    a renamed piece fails the table's test instead of going unstubbed."""
    tree = ast.parse(source)
    left = dict(pieces)

    def visit(body: list[ast.stmt], prefix: str) -> None:
        for node in body:
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                continue
            qualname = prefix + node.name
            if qualname in left:
                name, exercise = f"{module}:{qualname}", left.pop(qualname)
                if isinstance(node, ast.ClassDef):
                    init = ast.parse("def __init__(self, *args, **kwargs):\n    pass").body[0]
                    init.body = _raise(name, exercise)
                    node.body, node.decorator_list, node.keywords = [init], [], []
                else:
                    node.body = _raise(name, exercise)
            elif isinstance(node, ast.ClassDef):
                visit(node.body, qualname + ".")

    visit(tree.body, "")
    if left:
        raise KeyError(f"{module} has no {', '.join(sorted(left))} to stub")
    return ast.unparse(ast.fix_missing_locations(tree)) + "\n"


def package_dir() -> Path:
    """The folder of the installed ``vdtutorial`` package (a clone's, or site-packages')."""
    return Path(importlib.util.find_spec("vdtutorial").origin).resolve().parent


def module_file(package: Path, module: str) -> Path:
    """The source file of ``module`` (``vdtutorial.x.y``) in the package folder ``package``."""
    parts = module.split(".")[1:]
    path = package.joinpath(*parts)
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def stubbed_copy(destination: Path, exercises, package: Path | None = None) -> Path:
    """A copy of the package folder ``package`` (default: the installed one) at ``destination``, with the stubs of
    ``exercises`` written into its sources and no compiled bytecode (a ``.pyc`` would hold the original code).
    Returns ``destination``."""
    package = Path(package) if package is not None else package_dir()
    destination = Path(destination)
    shutil.copytree(package, destination, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo"))
    for module, pieces in targets(exercises).items():
        path = module_file(destination, module)
        path.write_text(stub_source(path.read_text(), module, pieces))
    return destination
