"""The library as the grading kernel sees it (vdtutorial/course/stubs.py): every piece an exercise rebuilds is a
stub in the copy, whatever the route to it, and nothing else of the package changes."""

import pkgutil
import subprocess
import sys

import nbformat
import numpy as np
import pytest

from vdtutorial.course import answer_rules, checks, classroom, stubs


def _exercises(*chapters: str) -> list[str]:
    return [exercise for exercise in stubs.STUBS if exercise.split("_")[0] in chapters]


@pytest.fixture(scope="module")
def stubbed(tmp_path_factory):
    """The copy of a kernel that grades chapters 04 and 06 at once (a real kernel stubs one chapter's exercises;
    these two chapters share no piece, so one copy serves the tests of both)."""
    return stubs.stubbed_copy(tmp_path_factory.mktemp("library") / "vdtutorial", _exercises("ch04", "ch06"))


def _in_copy(stubbed, code: str) -> subprocess.CompletedProcess:
    """``code`` run by a Python that imports the stubbed copy (its folder first on the path)."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={"PYTHONPATH": str(stubbed.parent), "PATH": "/usr/bin:/bin", "PYTHONDONTWRITEBYTECODE": "1"},
        cwd=stubbed.parent,
    )


def test_every_stub_names_a_piece_an_exercise_rebuilds_and_exists():
    for exercise, names in stubs.STUBS.items():
        assert exercise in answer_rules.FORBIDDEN, exercise
        checks.check(exercise)  # KeyError if the exercise has no trusted check
        for name in names:
            module, qualname = name.split(":")
            obj = pkgutil.resolve_name(name)  # the real one, here
            assert obj.__qualname__ == qualname and module.startswith("vdtutorial.")


@pytest.mark.parametrize("exercise", list(answer_rules.FORBIDDEN))
def test_every_name_an_exercise_forbids_is_a_stub_or_goes_through_one_or_is_given(exercise):
    """The static check forbids a name; the kernel must not have it working unless the table says why."""
    pieces = stubs.STUBS.get(exercise, ())
    stubbed = {part for piece in pieces for part in piece.split(":")[1].split(".")}
    through, given = stubs.THROUGH.get(exercise, {}), stubs.GIVEN.get(exercise, {})
    for name in answer_rules.FORBIDDEN[exercise]:
        ways = [name in stubbed, name in through, name in given]
        assert sum(ways) == 1, (exercise, name, ways)
    assert set(through.values()) <= set(pieces), exercise
    assert all(why.strip() for why in given.values())


def test_teaching_names_every_piece_the_kernel_keeps_working():
    text = (classroom.notebooks_dir() / "TEACHING.md").read_text()
    for exercise, given in stubs.GIVEN.items():
        for name in given:
            assert f"`{name}`" in text, (exercise, name)


def test_each_route_to_a_stubbed_piece_reaches_the_stub(stubbed):
    """Import, a string-built name, sys.modules, pickle of a global reference, importlib and runpy all give the
    stub; the original source is nowhere in the copy; the untouched pieces still work."""
    assert "r_dot_r" not in (stubbed / "trust_region.py").read_text() and not list(stubbed.rglob("*.pyc"))
    code = """
import importlib, pickle, pkgutil, runpy, sys, torch
import vdtutorial.vd
from vdtutorial.vd import LinearSVDO
routes = {
    "import": lambda: __import__("vdtutorial.trust_region", fromlist=["x"]).conjugate_gradient,
    "pkgutil": lambda: pkgutil.resolve_name("vdtutorial.trust_region:" + "conjugate_gradient"),
    "sys.modules": lambda: getattr(sys.modules["vdtutorial.trust_region"], "conjugate_gradient"),
    "pickle": lambda: pickle.loads(b"cvdtutorial.trust_region\\nconjugate_gradient\\n."),
    "importlib": lambda: importlib.import_module("vdtutorial.trust_region").conjugate_gradient,
    "runpy": lambda: runpy.run_module("vdtutorial.trust_region")["conjugate_gradient"],
}
for route, get in routes.items():
    try:
        get()(lambda v: v, torch.ones(2), 3)
        print(route, "REAL")
    except NotImplementedError as exc:
        print(route, "STUB", exc)
layer = LinearSVDO(3, 2).eval()
print("eval", tuple(layer(torch.ones(1, 3)).shape), "keep", tuple(layer.keep_mask().shape))
try:
    layer.train()(torch.ones(1, 3))
except NotImplementedError as exc:
    print("train STUB", exc)
"""
    run = _in_copy(stubbed, code)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    want = stubs.message("vdtutorial.trust_region:conjugate_gradient", "ch06_conjugate_gradient")
    for route in ("import", "pkgutil", "sys.modules", "pickle", "importlib", "runpy"):
        assert f"{route} STUB {want}" in lines, (route, lines)
    assert "eval (1, 2) keep (2, 3)" in lines
    assert any(line.startswith("train STUB") and "ch04_gaussian_dropout" in line for line in lines), lines


def test_chapter_07s_kernel_runs_a_pruned_layer_but_prunes_nothing_itself(tmp_path):
    """7.1's check runs the student's pruned copy, whose forward pass reads the mask the answer froze; the mask from
    log alpha (an unpruned layer's, also in its eval-mode forward pass) and every pruning routine are stubs. Chapter
    04's kernel, which keeps eval mode's forward pass, does not stub the mask: a kernel stubs one chapter."""
    assert "vdtutorial.vd:SVDOLayer.keep_mask" not in {p for e in _exercises("ch04") for p in stubs.STUBS[e]}
    copy = stubs.stubbed_copy(tmp_path / "vdtutorial", _exercises("ch07"))
    code = """
import pkgutil, torch
from vdtutorial.vd import LinearSVDO
layer = LinearSVDO(3, 2)
for name, call in {
    "eval": lambda: layer.eval()(torch.ones(1, 3)),
    "prune_": lambda: pkgutil.resolve_name("vdtutorial.vd:SVDOLayer." + "prune_")(layer),
    "kept_weights": lambda: pkgutil.resolve_name("vdtutorial.analysis.sparsity:kept_" + "weights")(layer),
    "curves": lambda: pkgutil.resolve_name("vdtutorial.experiments:curves_from_" + "rows")([], "successes", 1),
}.items():
    try:
        call()
        print(name, "REAL")
    except NotImplementedError as exc:
        print(name, "STUB", exc)
with torch.no_grad():
    layer.mask.copy_(torch.tensor([[True, False, True], [False, True, True]]))
    layer.pruned.fill_(True)
print("pruned", layer.train()(torch.ones(1, 3)).tolist() == layer.eval()(torch.ones(1, 3)).tolist(),
      torch.equal(layer.keep_mask(), layer.mask))
"""
    run = _in_copy(copy, code)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    for name, piece, exercise in (
        ("eval", "vdtutorial.vd:SVDOLayer.keep_mask", "ch07_prune"),
        ("prune_", "vdtutorial.vd:SVDOLayer.prune_", "ch07_prune"),
        ("kept_weights", "vdtutorial.analysis.sparsity:kept_weights", "ch07_prune"),
        ("curves", "vdtutorial.experiments.curves:curves_from_rows", "ch07_steps_to_level"),
    ):
        assert f"{name} STUB {stubs.message(piece, exercise)}" in lines, (name, lines)
    assert "pruned True True" in lines, lines


def test_the_checks_verdicts_are_stubs_in_the_kernel_and_their_probes_are_not(stubbed):
    """A verdict recomputes the answer (4.1's eq. 4 inline): in the kernel it would be a reference to call."""
    source = (stubbed / "course" / "checks" / "ch04.py").read_text()
    assert "einsum" not in source and "def dropout_probe" in source
    assert stubs.verdicts("ch04") == {
        "ch04_gaussian_dropout": "dropout_verdict",
        "ch04_svdo_layer": "layer_verdict",
        "ch04_compact": "compact_verdict",
    }
    run = _in_copy(stubbed, "from vdtutorial.course.checks import ch04\nch04.dropout_verdict({}, {})\n")
    assert stubs.message("vdtutorial.course.checks.ch04:dropout_verdict", "ch04_gaussian_dropout") in run.stderr


def test_only_the_graders_own_stub_lines_are_believed():
    line = stubs.message("vdtutorial.analysis.compact:compact", "ch04_compact")
    assert checks.stubbed(f"NotImplementedError: {line}") == line
    forged = line.replace("compact:compact", "compact:anything").replace("ch04_compact", "ch04_x")
    assert checks.stubbed(forged) is None and checks.stubbed("your code raised KeyError") is None


def test_grading_runs_the_hidden_tests_first(tmp_path):
    path = tmp_path / "06b.ipynb"
    path.write_bytes(classroom.chapters()["06b_trpo_assembled"].read_bytes())
    classroom.hidden_tests_first(path)
    before = nbformat.read(classroom.chapters()["06b_trpo_assembled"], as_version=4).cells
    after = nbformat.read(path, as_version=4).cells
    tests = [k for k, c in enumerate(before) if c.metadata.get("nbgrader", {}).get("grade")]
    assert tests
    for k in tests:
        assert after[k].source.startswith("### BEGIN HIDDEN TESTS\n")
        assert sorted(after[k].source.splitlines()) == sorted(before[k].source.splitlines())
    assert [c.source for k, c in enumerate(after) if k not in tests] == [
        c.source for k, c in enumerate(before) if k not in tests
    ]


def test_each_exercise_gets_its_inputs_in_its_turn_and_its_outputs_are_sealed_after(tmp_path):
    """An exercise's inputs appear as its tests cell starts, in the chapter's order; its outputs leave the
    kernel's folder when the cell ends (a later cell cannot rewrite them); a tests cell out of turn (a copy of a
    later exercise's, moved up) gets nothing."""
    exchange, sealed = tmp_path / "exchange", tmp_path / "sealed"
    exchange.mkdir()
    sealed.mkdir()
    drawn = {name: {"x": np.arange(3.0) + k} for k, name in enumerate(("ch04_gaussian_dropout", "ch04_compact"))}
    turns = classroom._Exchange(exchange, sealed, drawn)

    def cell(grade_id):
        return nbformat.v4.new_code_cell("", metadata={"nbgrader": {"grade_id": grade_id}})

    turns.before(cell=cell("ch04_compact_tests"))  # out of turn
    assert not list(exchange.iterdir())
    turns.before(cell=cell("ch04_gaussian_dropout_tests"))
    assert [p.name for p in exchange.iterdir()] == ["ch04_gaussian_dropout.inputs.npz"]
    checks.save(checks.outputs_path(exchange, "ch04_gaussian_dropout"), {"y": np.ones(2)})
    turns.before(cell=cell("ch04_svdo_layer"))  # the next cell: the exercise's turn is over
    assert not list(exchange.iterdir())
    checks.save(checks.outputs_path(exchange, "ch04_gaussian_dropout"), {"y": np.zeros(2)})  # a later rewrite
    assert np.array_equal(turns.outputs("ch04_gaussian_dropout")["y"], np.ones(2))
    turns.before(cell=cell("ch04_compact_tests"))
    assert np.array_equal(checks.load(checks.inputs_path(exchange, "ch04_compact"))["x"], drawn["ch04_compact"]["x"])
    turns.after()  # the notebook ended; no outputs came back
    assert turns.outputs("ch04_compact") is None
