"""The static check of an answer cell (vdtutorial/course/answer_rules.py): one FORBIDDEN entry per exercise of the
chapters, each naming the library's own pieces; the teacher's solutions pass it; hostile answers do not."""

import ast
import importlib.util
import json
import textwrap
from pathlib import Path

import pytest

from vdtutorial.course import classroom
from vdtutorial.course.answer_rules import FORBIDDEN, answer_violations


def _nbgrader_cells():
    """(notebook name, position, nbgrader metadata, source) of every nbgrader cell of the teacher's chapters."""
    cells = []
    for name, path in classroom.chapters().items():
        for position, cell in enumerate(json.loads(Path(path).read_text())["cells"]):
            meta = cell.get("metadata", {}).get("nbgrader")
            if meta:
                source = cell["source"] if isinstance(cell["source"], str) else "".join(cell["source"])
                cells.append((name, position, meta, source))
    return cells


CELLS = _nbgrader_cells()
ANSWERS = [(name, meta["grade_id"], source) for name, _, meta, source in CELLS if meta.get("solution")]


def test_every_answer_cell_has_its_forbidden_names_and_its_test_cell():
    answer_ids = [grade_id for _, grade_id, _ in ANSWERS]
    assert len(answer_ids) == len(set(answer_ids)) == 31, answer_ids
    assert list(FORBIDDEN) == answer_ids, "one FORBIDDEN entry per answer cell, in the order of the chapters"
    by_notebook = {}
    for name, position, meta, _ in CELLS:
        by_notebook.setdefault(name, []).append((position, meta))
    for name, cells in by_notebook.items():
        answers = {meta["grade_id"]: position for position, meta in cells if meta.get("solution")}
        tests = {meta["grade_id"]: position for position, meta in cells if not meta.get("solution")}
        assert all(meta.get("grade") for position, meta in cells if not meta.get("solution")), name
        assert set(tests) == {f"{grade_id}_tests" for grade_id in answers}, (name, sorted(tests), sorted(answers))
        assert all(tests[f"{grade_id}_tests"] == position + 1 for grade_id, position in answers.items()), (
            f"{name}: each answer cell is followed by its test cell"
        )


def test_the_forbidden_names_are_identifiers_each_once():
    for grade_id, names in FORBIDDEN.items():
        assert isinstance(names, tuple) and names, grade_id
        assert all(isinstance(n, str) and n.isidentifier() for n in names), grade_id
        assert len(set(names)) == len(names), grade_id


@pytest.mark.parametrize("grade_id, source", [(g, s) for _, g, s in ANSWERS], ids=[g for _, g, _ in ANSWERS])
def test_the_teachers_solution_passes(grade_id, source):
    assert "### BEGIN SOLUTION" in source
    found = answer_violations(source, FORBIDDEN[grade_id])
    assert not found, "\n".join(f"{v.kind}, {v}" for v in found)


def _library_names() -> set[str]:
    """Every name vdtutorial defines: module-level functions, classes and assigned names (importable attributes),
    and the methods (and properties) of its classes."""
    package = Path(importlib.util.find_spec("vdtutorial").submodule_search_locations[0])
    names = set()
    for path in package.rglob("*.py"):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
            if isinstance(node, ast.ClassDef):
                names |= {item.name for item in node.body if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef))}
    return names


def test_each_forbidden_name_is_defined_in_the_library():
    defined = _library_names()
    assert {"LinearSVDO", "conjugate_gradient", "_goal_status", "prune_"} <= defined  # the walk finds all kinds
    missing = {grade_id: [n for n in names if n not in defined] for grade_id, names in FORBIDDEN.items()}
    assert not any(missing.values()), {g: m for g, m in missing.items() if m}


# (exercise, answer source, the kind of violation it must raise, words of that violation's text)
HOSTILE = {
    "the reference under the student's name": (
        "ch04_svdo_layer",
        "from vdtutorial.vd import LinearSVDO as MyLinearSVDO",
        "forbidden",
        "LinearSVDO",
    ),
    "the reference through its module": (
        "ch06_conjugate_gradient",
        """
        import vdtutorial.trust_region as tr

        def my_cg(Avp, b, iters):
            return tr.conjugate_gradient(Avp, b, iters)
        """,
        "forbidden",
        "conjugate_gradient",
    ),
    "the reference named in a string": (
        "ch10_holm",
        """
        from vdtutorial.experiments import effects

        def holm(p_values, alpha=0.05):
            return getattr(effects, "holm_rejections")(p_values, alpha)
        """,
        "forbidden",
        "holm_rejections in a string",
    ),
    "getattr with a computed name": (
        "ch10_holm",
        """
        from vdtutorial.experiments import effects

        def holm(p_values, alpha=0.05):
            return getattr(effects, "holm_" + "rejections")(p_values, alpha)
        """,
        "tampering",
        "getattr with a name",
    ),
    "importlib": (
        "ch06_gae",
        """
        import importlib

        def my_gae(rewards, values, last_value, dones, gamma, lam):
            return importlib.import_module("vdtutorial.trpo").__getattribute__("g" + "ae")(
                rewards, values, last_value, dones, gamma, lam)
        """,
        "tampering",
        "importlib",
    ),
    "torch.testing.assert_close reassigned": (
        "ch06_conjugate_gradient",
        "torch.testing.assert_close = lambda *args, **kwargs: None",
        "tampering",
        "torch.testing.assert_close",
    ),
    "np.testing.assert_allclose through an alias": (
        "ch06_reinforce",
        "t = np.testing\nt.assert_allclose = lambda *args, **kwargs: None",
        "tampering",
        "t.assert_allclose",
    ),
    "math.isclose reassigned": (
        "ch01_reward_eq11",
        "math.isclose = lambda *args, **kwargs: True",
        "tampering",
        "math.isclose",
    ),
    "a builtin reassigned": ("ch10_holm", "import builtins\nbuiltins.abs = lambda x: 0", "tampering", "builtins.abs"),
    "a library function reassigned": (
        "ch10_holm",
        "import vdtutorial.vd\nvdtutorial.vd.LinearSVDO.kl = lambda self: 0",
        "tampering",
        "vdtutorial.vd.LinearSVDO.kl",
    ),
    "the kernel's traceback patched": (
        "ch10_holm",
        "get_ipython().showtraceback = lambda *args, **kwargs: None",
        "tampering",
        "showtraceback",
    ),
    "the grader's own checks imported": (
        "ch02_step_towards",
        "from vdtutorial.course.checks import ch02",
        "tampering",
        "vdtutorial.course",
    ),
    "the grader's package imported whole": (
        "ch02_step_towards",
        "import vdtutorial.course.classroom as grader",
        "tampering",
        "vdtutorial.course",
    ),
    "os._exit": ("ch10_holm", "import os\nos._exit(0)", "tampering", "_exit"),
    "sys.exit": ("ch10_holm", "import sys\nsys.exit()", "tampering", "uses exit"),
    "exit": ("ch10_holm", "exit()", "tampering", "uses exit"),
    "a class whose __eq__ is always True": (
        "ch06_gae",
        """
        class Anything:
            def __eq__(self, other):
                return True

        def my_gae(rewards, values, last_value, dones, gamma, lam):
            return Anything()
        """,
        "tampering",
        "Anything.__eq__",
    ),
    "a tensor subclass with __torch_function__": (
        "ch06_conjugate_gradient",
        """
        class Agreeable(torch.Tensor):
            @classmethod
            def __torch_function__(cls, func, types, args=(), kwargs=None):
                return torch.tensor(True)
        """,
        "tampering",
        "Agreeable.__torch_function__",
    ),
    "an ndarray subclass with __array_ufunc__": (
        "ch06_reinforce",
        """
        class Agreeable(np.ndarray):
            def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
                return np.zeros(())
        """,
        "tampering",
        "Agreeable.__array_ufunc__",
    ),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_answer_is_flagged(case):
    grade_id, source, kind, words = HOSTILE[case]
    found = answer_violations(textwrap.dedent(source), FORBIDDEN[grade_id])
    assert any(v.kind == kind and words in v.text for v in found), (case, [f"{v.kind}, {v}" for v in found])


CLEAN = {
    "a small nn.Module": (
        "ch04_svdo_layer",
        """
        class TwoLayers(nn.Module):
            def __init__(self, n_in, n_out, hidden=8):
                super().__init__()
                self.hidden = nn.Linear(n_in, hidden)
                self.out = nn.Linear(hidden, n_out)
                self.scale = nn.Parameter(torch.ones(n_out))

            def forward(self, x):
                return self.scale * self.out(torch.relu(self.hidden(x)))
        """,
    ),
    "a deep copy of the argument, edited": (
        "ch07_prune",
        """
        def prune_for_rl(policy, threshold=THRESHOLD):
            pruned = copy.deepcopy(policy)
            with torch.no_grad():
                for layer in svdo_layers(pruned):
                    keep = layer.log_sigma2 - torch.log(layer.weight ** 2 + 1e-8) <= threshold
                    layer.weight.mul_(keep)
                    layer.mask[...] = keep
                    layer.pruned.fill_(True)
                    layer.log_sigma2.requires_grad = False
            pruned.pruned_at = threshold
            return pruned
        """,
    ),
}


@pytest.mark.parametrize("case", list(CLEAN))
def test_a_clean_answer_passes(case):
    grade_id, source = CLEAN[case]
    assert answer_violations(textwrap.dedent(source), FORBIDDEN[grade_id]) == []


@pytest.mark.parametrize("grade_id, source", [(g, s) for _, g, s in ANSWERS], ids=[g for _, g, _ in ANSWERS])
def test_every_exercise_refuses_its_reference_and_any_patch(grade_id, source):
    """Against every exercise: the teacher's right answer, with the library's piece imported or a test function
    patched in front of it, is flagged (so it scores 0 there, or the whole notebook does)."""
    for name in FORBIDDEN[grade_id]:
        imported = f"from vdtutorial.some_module import {name} as mine\n" + source
        assert any(v.kind == "forbidden" for v in answer_violations(imported, FORBIDDEN[grade_id])), name
    for patch in (
        "import numpy as np\nnp.testing.assert_allclose = print\n",
        "get_ipython().showtraceback = print\n",
        "class Same(float):\n    def __eq__(self, other):\n        return True\n",
    ):
        assert any(v.kind == "tampering" for v in answer_violations(patch + source, FORBIDDEN[grade_id])), patch


def test_the_teachers_chapters_are_refused_nothing():
    from vdtutorial.course import classroom

    for name, path in classroom.chapters().items():
        assert classroom.refusals(path, path) == (None, {}), name


def test_an_added_cell_or_a_changed_chapter_cell_is_checked_for_what_it_adds(tmp_path):
    """nbgrader restores only the locked cells: a student can add a cell, or change an ordinary one of the chapter.
    Only what the student's version adds counts (the chapter's own cells use the library freely)."""
    import nbformat

    from vdtutorial.course import classroom

    teacher = classroom.chapters()["04_sparse_variational_dropout"]
    nb = nbformat.read(teacher, as_version=4)
    nb.cells.insert(5, nbformat.v4.new_code_cell("from vdtutorial.vd import LinearSVDO as Base"))
    setup = next(
        c
        for c in nb.cells
        if c.cell_type == "code"
        and "import" in c.source
        and c.get("id") != nb.cells[5].get("id")
        and "vdtutorial.vd" in c.source
    )
    setup.source += "\nprint('my note')"
    nbformat.write(nb, tmp_path / "added.ipynb")
    whole, each = classroom.refusals(tmp_path / "added.ipynb", teacher)
    assert whole is None and set(each) == {"ch04_svdo_layer_tests"} and "LinearSVDO" in each["ch04_svdo_layer_tests"]
    setup.source += "\nimport torch\ntorch.testing.assert_close = print"
    nbformat.write(nb, tmp_path / "patched.ipynb")
    whole, _ = classroom.refusals(tmp_path / "patched.ipynb", teacher)
    assert whole and "changes torch.testing.assert_close" in whole and "not an answer cell" in whole
