"""The library's layout: the grid runner apart from the science, and every module pointing at the chapter that
teaches it (d2l style)."""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path

import pytest

import vdtutorial
from vdtutorial.settings import shipped_dir

PACKAGE = Path(vdtutorial.__file__).parent
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if "book" not in p.relative_to(PACKAGE).parts[:1])
#: What the grid runner may import from the package: nothing that knows about VD, TRPO or policies.
RUNNER_MAY_IMPORT = ("vdtutorial.runner", "vdtutorial.settings")
#: "Taught in chapter 07" / "Taught in chapters 05 and 07" / "Not taught in a chapter: REASON".
TAUGHT = re.compile(
    r"Taught in (?:chapters?|appendix) ((?:(?:\d\d[a-z]?|A\d)(?:, | and | and appendix )?)+)"
    r"|Not taught in a chapter: \S"
)


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _dotted(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return {name for name in names if name.split(".")[0] == "vdtutorial"}


def test_the_runner_imports_nothing_of_the_science():
    for path in sorted((PACKAGE / "runner").glob("*.py")):
        for name in _imported(_tree(path)):
            assert name.startswith(RUNNER_MAY_IMPORT), f"{path.name} imports {name}"


def test_the_experiments_hold_no_grid_lock_backend_or_resume_code():
    runner_names = {
        node.name
        for path in (PACKAGE / "runner").glob("*.py")
        for node in _tree(path).body
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and not node.name.startswith("_")
    }
    for path in sorted((PACKAGE / "experiments").glob("*.py")):
        defined = {node.name for node in _tree(path).body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
        assert not defined & runner_names, f"{path.name} defines the runner's {sorted(defined & runner_names)}"
    assert {"grid", "backends", "resume", "run_lock", "progress", "rows"}.isdisjoint(
        p.stem for p in (PACKAGE / "experiments").glob("*.py")
    )


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_a_module_docstring_names_the_chapter_that_teaches_it(path):
    doc = ast.get_docstring(_tree(path))
    assert doc, "no module docstring"
    match = TAUGHT.search(" ".join(doc.split()))
    assert match, "the docstring names no chapter ('Taught in chapter NN' or 'Not taught in a chapter: why')"
    if match.group(1) is None:
        return
    chapters = {p.name.split("_")[0]: p for p in (shipped_dir() / "notebooks").glob("*.ipynb")}
    relative = path.relative_to(PACKAGE.parent)
    names = (_dotted(path), str(relative), *([f"{relative.parent}/"] if path.name == "__init__.py" else []))
    for number in re.findall(r"\d\d[a-z]?|A\d", match.group(1)):
        assert number in chapters, f"chapter {number} does not exist"
        text = "".join("".join(cell["source"]) for cell in json.loads(chapters[number].read_text())["cells"])
        assert any(re.search(re.escape(name) + r"\b", text) for name in names), (
            f"chapter {chapters[number].name} does not mention {names[0]}"
        )


#: A pointer to a docstring section: "module docstring" or a class of the same module, then the quoted words to look
#: for.
POINTER = re.compile(r'(module docstring|:class:`~?([\w.]+)`),\s+"([^"]+)"')


def _pointers_and_targets(path: Path) -> list[tuple[int, str, str]]:
    """Each "module docstring" mention and each quoted class section in ``path``: (line, words, the text pointed at)."""
    tree, text = _tree(path), path.read_text()
    docs = {"module docstring": ast.get_docstring(tree) or ""}
    docs.update({node.name: ast.get_docstring(node) or "" for node in ast.walk(tree) if isinstance(node, ast.ClassDef)})
    module_doc = tree.body[0].end_lineno if docs["module docstring"] else 0
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        if number <= module_doc:
            continue
        pointers = list(POINTER.finditer(line))
        if "module docstring" in line and not any(m.group(1) == "module docstring" for m in pointers):
            found.append((number, line.strip(), ""))  # a bare "see the module docstring": says nothing to look for
        for match in pointers:
            target = docs.get(match.group(2).rsplit(".", 1)[-1] if match.group(2) else "module docstring")
            if target is not None:
                found.append((number, match.group(3), " ".join(target.split())))
    return found


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_a_pointer_to_a_docstring_names_words_that_are_there(path):
    dangling = [
        f"line {n}: {words!r}"
        for n, words, target in _pointers_and_targets(path)
        if " ".join(words.split()) not in target
    ]
    assert not dangling
