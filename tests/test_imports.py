"""Imports point down and form no cycle: every import statement of the package, at module level
and inside functions, read with ``ast`` (nothing is imported to find them).

The rooms and their order are DESIGN.md's "Package layout": cli, viewer -> render, tiles ->
tree, textures, rd -> patches, io -> geometry -> kernels, with errors and _version at the very
bottom and the package root (``approxtree/__init__.py``) free to import anything. Imports under
``if TYPE_CHECKING:`` never run and are left out; so are names built at run time
(``importlib.import_module`` of an f-string, as ``approxtree.tree.__init__`` does).
"""

from __future__ import annotations

import ast
import tomllib
from dataclasses import dataclass
from pathlib import Path

import approxtree
from approxtree import _version

PACKAGE = Path(approxtree.__file__).resolve().parent
PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"

#: Level of each room (a subpackage or top-level module of approxtree; "" is the package root).
#: A module imports modules of its own room and of rooms on lower levels only.
LEVELS = {
    # The bottom: they import nothing of ours (progress: the callback protocol of long runs).
    "errors": 0,
    "_version": 0,
    "progress": 0,
    # The loader of the package's GLSL programs (render/ draws with them, textures/ bakes).
    "glsl": 1,
    "kernels": 1,
    "geometry": 2,
    "io": 3,
    "patches": 3,
    "tree": 4,
    "textures": 4,
    "rd": 4,
    # Sample terrains (read and written through io); verify reads outputs without writer code.
    "datasets": 4,
    "verify": 4,
    "render": 5,
    "tiles": 5,
    "viewer": 6,
    # cli starts the viewer; the notebook widget shows it in Jupyter.
    "cli": 7,
    "notebook": 7,
    "": 8,
    # Entry points: python -m approxtree, and the install-time kernel warm-up.
    "__main__": 9,
    "_warmup": 9,
}


@dataclass(frozen=True)
class Import:
    """One import statement: importer → imported module, its line, inside a function or not."""

    importer: str
    imported: str
    line: int
    in_function: bool

    def __str__(self) -> str:
        where = "inside a function" if self.in_function else "at module level"
        return f"{self.importer} imports {self.imported} (line {self.line}, {where})"


@dataclass(frozen=True)
class Violation:
    """A cycle or an upward import, with the modules it involves."""

    text: str
    modules: tuple[str, ...]


def modules() -> dict[str, Path]:
    """Dotted name → file of every module of the package."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def room(module: str) -> str:
    """The room of a dotted module name ("" for the package root)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes inside ``if TYPE_CHECKING:`` blocks."""
    skipped = set()
    for node in ast.walk(tree):
        test = node.test if isinstance(node, ast.If) else None
        name = getattr(test, "id", None) or getattr(test, "attr", None)
        if name == "TYPE_CHECKING":
            for inner in node.body:
                skipped.update(id(n) for n in ast.walk(inner))
    return skipped


def _targets(node: ast.AST, module: str, is_package: bool, known: dict[str, Path]) -> list[str]:
    """The approxtree modules an import statement (or importlib call) names."""
    names: list[str] = []
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    elif isinstance(node, ast.ImportFrom):
        base = node.module or ""
        if node.level:
            here = module.split(".") if is_package else module.split(".")[:-1]
            here = here[: len(here) - (node.level - 1)]
            base = ".".join([*here, *([base] if base else [])])
        # ``from a import b``: the submodule a.b when there is one, else a itself.
        names = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
    elif (
        isinstance(node, ast.Call)
        and getattr(node.func, "attr", None) == "import_module"
        and node.args
        and isinstance(node.args[0], ast.Constant)
    ):
        names = [str(node.args[0].value)]
    out = []
    for name in names:
        # The longest prefix that is a module of ours (``import approxtree.x.y`` → approxtree.x.y).
        while name and name not in known:
            name = name.rpartition(".")[0]
        if name and name != module and name not in out:
            out.append(name)
    return out


def imports() -> list[Import]:
    """Every import of an approxtree module by another, module-level and in functions."""
    known = modules()
    found = []
    for module, path in known.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        skipped = _type_checking_only(tree)
        functions = [
            n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
        ]
        in_function = {id(inner) for f in functions for inner in ast.walk(f)}
        for node in ast.walk(tree):
            if id(node) in skipped:
                continue
            for target in _targets(node, module, path.name == "__init__.py", known):
                found.append(Import(module, target, node.lineno, id(node) in in_function))
    return found


def _cycles(edges: list[Import]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iteratively)."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        graph.setdefault(e.importer, set()).add(e.imported)
        graph.setdefault(e.imported, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    return components


def violations() -> list[Violation]:
    """Every import cycle and every import of a room on the same or a higher level."""
    edges = imports()
    out = []
    for component in _cycles(edges):
        inside = set(component)
        lines = "; ".join(str(e) for e in edges if e.importer in inside and e.imported in inside)
        out.append(
            Violation(f"import cycle among {', '.join(component)}: {lines}", tuple(component))
        )
    for e in edges:
        a, b = room(e.importer), room(e.imported)
        if a != b and LEVELS[b] >= LEVELS[a]:
            text = (
                f"{e} — room {b or 'root'!r} (level {LEVELS[b]}) is not below {a!r} ({LEVELS[a]})"
            )
            out.append(Violation(text, (e.importer, e.imported)))
    return out


def _report(found: list[Violation]) -> str:
    return "\n".join(["imports that do not point down:", *(f"  - {v.text}" for v in found)])


def test_every_room_has_a_level():
    """Every subpackage and top-level module of approxtree is placed in LEVELS."""
    rooms = {room(m) for m in modules()}
    assert rooms <= set(LEVELS), f"place these rooms in LEVELS: {sorted(rooms - set(LEVELS))}"


def test_imports_are_found_inside_functions_too():
    """The scan sees function-level imports (io.own_output's deferred io.gdal) and skips
    TYPE_CHECKING blocks (tree.cut_mesh's ApproximationTree)."""
    edges = {(e.importer, e.imported): e for e in imports()}
    assert edges[("approxtree.io.own_output", "approxtree.io.gdal")].in_function
    assert ("approxtree.tree.cut_mesh", "approxtree.tree.approximation_tree") not in edges


def test_no_cycles_and_only_downward_imports():
    """No import cycle among the package's modules (imports in functions count) and no room
    imports a room on its own or a higher level."""
    found = violations()
    assert not found, _report(found)


def test_the_version_has_one_source():
    """approxtree._version holds the version: the package root re-exports it and
    pyproject.toml reads it from there (no second literal)."""
    assert approxtree.__version__ is _version.__version__
    project = tomllib.loads(PYPROJECT.read_text())
    assert "version" in project["project"]["dynamic"] and "version" not in project["project"]
    dynamic = project["tool"]["setuptools"]["dynamic"]["version"]
    assert dynamic == {"attr": "approxtree._version.__version__"}
