"""Imports go one way. The package is a stack of layers -- the core (the paper's method: the modules directly in
``vdtutorial/`` and ``envs/``), then the speed-ups, the analyses, the grid runner and the methods beyond the paper,
then the experiments, then the course, then the command line -- and a module imports only from its own layer and
those below it (anywhere in the file: the command line's imports inside functions count too). Within the package
no module imports one that imports it back, directly or through others.

One list records what has not been cut yet; it may only shrink (the tests say when an entry is cut)."""

from __future__ import annotations

import ast
from pathlib import Path

import vdtutorial

PACKAGE = Path(vdtutorial.__file__).parent
#: Each layer and the layers below it that it may import from (its own is always allowed).
MAY_IMPORT = {
    "core": set(),
    "fast": {"core"},
    "analysis": {"core"},
    "runner": {"core"},
    "beyond": {"core"},
    "experiments": {"core", "fast", "analysis", "runner", "beyond"},
    "course": {"core", "fast", "analysis", "runner", "beyond", "experiments"},
    "cli": {"core", "fast", "analysis", "runner", "beyond", "experiments", "course"},
}
#: Imports against the direction still to be cut: (importing module, imported module).
NOT_YET_CUT = {("vdtutorial", "vdtutorial.course.install_check")}
#: Modules that import each other, still to be separated: sorted pairs.
NOT_YET_SEPARATED: set = set()


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def _imports(path: Path, known: set[str]) -> set[str]:
    """The package's modules that ``path`` imports, anywhere in the file (``from vdtutorial import x`` is the
    module ``vdtutorial.x`` when there is one, else the package)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "vdtutorial":
            for alias in node.names:
                found.add(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in known else node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.split(".")[0] == "vdtutorial")
    return found


def _layer(module: str) -> str:
    parts = module.split(".")
    if module == "vdtutorial.__main__":  # ``python -m vdtutorial``: the command line's entry point
        return "cli"
    if len(parts) == 1 or parts[1] == "envs" or (len(parts) == 2 and (PACKAGE / f"{parts[1]}.py").exists()):
        return "core"
    return parts[1]


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, set(modules)) - {name} for name, path in modules.items()}


def test_every_subpackage_has_a_place_in_the_stack():
    layers = {_layer(name) for name in _modules()}
    assert layers == set(MAY_IMPORT), f"place {sorted(layers - set(MAY_IMPORT))} in MAY_IMPORT"


def test_no_module_imports_from_a_layer_above_its_own():
    against = {
        (module, imported)
        for module, imports in _graph().items()
        for imported in imports
        if _layer(imported) not in MAY_IMPORT[_layer(module)] | {_layer(module)}
    }
    assert against <= NOT_YET_CUT, f"imports against the direction: {sorted(against - NOT_YET_CUT)}"
    assert not NOT_YET_CUT - against, f"cut, so strike them from NOT_YET_CUT: {sorted(NOT_YET_CUT - against)}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan's algorithm): modules that reach each other."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return groups


def test_no_two_modules_import_each_other():
    cycles = {tuple(group) for group in _cycles(_graph())}
    assert cycles <= NOT_YET_SEPARATED, f"modules that import each other: {sorted(cycles - NOT_YET_SEPARATED)}"
    assert not NOT_YET_SEPARATED - cycles, f"separated, so strike them: {sorted(NOT_YET_SEPARATED - cycles)}"


def test_the_checks_see_an_import_against_the_direction_and_a_cycle():
    """The checks themselves: a core module importing the experiments, and two modules importing each other."""
    graph = {
        "vdtutorial.pretrain": {"vdtutorial.experiments.runs"},
        "vdtutorial.experiments.runs": set(),
        "vdtutorial.beyond.a": {"vdtutorial.beyond.b"},
        "vdtutorial.beyond.b": {"vdtutorial.beyond.a"},
    }
    assert _layer("vdtutorial.experiments.runs") not in MAY_IMPORT[_layer("vdtutorial.pretrain")]
    assert _cycles(graph) == [["vdtutorial.beyond.a", "vdtutorial.beyond.b"]]
