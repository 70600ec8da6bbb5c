"""Sphinx extension: the API reference pages, written from the packages' ``__all__``.

Before Sphinx reads the sources (``builder-inited``), one page per public subpackage or module
is written into docs/api/ (``api/<name>.rst``): the module docstring, a summary table and one
autodoc entry per public name, in the package's own ``__all__`` order. A name that a package
re-exports is documented under that package (``approxtree.render.Engine``), not under the
private module that defines it; ``api/index.rst`` lists every name of ``approxtree.__all__``
with a link to its page. So a public name added to an ``__all__`` appears without editing the
docs, and a page never lists a private helper.

Type hints name classes by their defining module (``approxtree.render.camera.Camera``); the
``missing-reference`` handler resolves such a target, and a bare or top-level one
(``Camera``, ``approxtree.Camera``), to the public name documented here.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from pathlib import Path
from typing import Any

from sphinx.pycode import ModuleAnalyzer
from sphinx.util import logging

logger = logging.getLogger(__name__)

#: The public subpackages and modules, in the order of the reference's table of contents.
#: approxtree.kernels (numba hot loops behind the patches) and approxtree.cli (see the CLI
#: reference) are not listed.
PUBLIC = (
    "approxtree.geometry",
    "approxtree.io",
    "approxtree.patches",
    "approxtree.tree",
    "approxtree.textures",
    "approxtree.render",
    "approxtree.tiles",
    "approxtree.rd",
    "approxtree.verify",
    "approxtree.viewer",
    "approxtree.notebook",
    "approxtree.datasets",
    "approxtree.progress",
    "approxtree.errors",
)

#: One-line description per page, for the reference's index.
BLURBS = {
    "approxtree.geometry": "Terrain data types: grids, non-regular grids, TINs, point sets.",
    "approxtree.io": "Readers: every raster, height PNGs, arrays, SCAPE, LAS/LAZ, quantized-mesh.",
    "approxtree.patches": "Geometry patches, the approximation strategies.",
    "approxtree.tree": "Approximation trees, strategy policies, the point quadtree, the store.",
    "approxtree.textures": "Shading, thematic layers, palettes, texture pyramids and patches.",
    "approxtree.render": "Camera, visual errors, selection and the moderngl Engine.",
    "approxtree.tiles": "OGC 3D Tiles and Cesium quantized-mesh writers.",
    "approxtree.rd": "Rate–distortion on the embedded right-triangle binary tree.",
    "approxtree.verify": "Independent checks of every output against its source.",
    "approxtree.viewer": "The interactive viewer and its pure parts.",
    "approxtree.notebook": "Previews and the orbiting widget in Jupyter.",
    "approxtree.datasets": "Sample terrains: matplotlib's DEM, fractal terrain, the case study.",
    "approxtree.progress": "Progress callbacks and the CLI's bars.",
    "approxtree.errors": "The exception and warning hierarchy.",
}


#: Classes that public functions return or public classes derive from, documented under their
#: defining module on the page of their package.
EXTRAS = {
    "approxtree.patches": (
        "approxtree.patches.mesh_objects.MeshConversions",
        "approxtree.patches.lattice.LatticePatch",
        "approxtree.patches.lattice.Window",
        "approxtree.patches.grid.GridPatchArrays",
    ),
    "approxtree.tree": (
        "approxtree.tree.cut_mesh.CutMesh",
        "approxtree.tree.policy.LevelPolicy",
        "approxtree.tree.patch_table.PatchTable",
        "approxtree.tree.store.TreeSource",
        "approxtree.tree.builder.BuiltLevels",
        "approxtree.tree.update.TreeUpdate",
    ),
    "approxtree.render": (
        "approxtree.render.lod_cut.LODCut",
        "approxtree.render.lod_cut.LODMesh",
        "approxtree.render.provider.Payload",
        "approxtree.render.provider.PayloadProvider",
    ),
}


def public_names(modname: str) -> list[str]:
    """The module's ``__all__``; without one, the classes and functions it defines."""
    module = importlib.import_module(modname)
    names = getattr(module, "__all__", None)
    if names is not None:
        return list(names)
    return [
        name
        for name, obj in vars(module).items()
        if not name.startswith("_")
        and (inspect.isclass(obj) or inspect.isfunction(obj))
        and getattr(obj, "__module__", None) == modname
    ]


def _kind(obj: Any) -> str:
    """The autodoc directive that documents ``obj``."""
    if inspect.isclass(obj):
        return "autoexception" if issubclass(obj, BaseException) else "autoclass"
    if inspect.isroutine(obj) or (callable(obj) and hasattr(obj, "__wrapped__")):
        return "autofunction"
    if callable(obj) and hasattr(obj, "py_func"):  # a numba dispatcher
        return "autofunction"
    return "data"


def _attr_doc(modname: str, name: str, obj: Any) -> list[str]:
    """The ``#:`` comment of a module-level constant, looked up in every submodule of the
    package holding the same object; [] when there is none."""
    package = importlib.import_module(modname)
    candidates = [modname]
    if hasattr(package, "__path__"):
        candidates += [
            info.name for info in pkgutil.iter_modules(package.__path__, prefix=modname + ".")
        ]
    for candidate in candidates:
        try:
            module = importlib.import_module(candidate)
        except ImportError:
            continue
        if getattr(module, name, None) is not obj:
            continue
        docs = ModuleAnalyzer.for_module(candidate).find_attr_docs()
        if ("", name) in docs:
            return [line for line in docs[("", name)] if line is not None]
    return []


def module_page(modname: str) -> tuple[str, dict[str, str]]:
    """The reST of one module's page, and {real qualified name: public name} of its objects."""
    module = importlib.import_module(modname)
    names = public_names(modname)
    kinds = {name: _kind(getattr(module, name)) for name in names}
    aliases: dict[str, str] = {}
    lines = [
        modname,
        "=" * len(modname),
        "",
        f".. automodule:: {modname}",
        "   :no-members:",
        "",
        f".. currentmodule:: {modname}",
        "",
    ]
    # The summary table holds classes and functions (a constant's docstring would be its
    # type's: dict's).
    routines = [name for name in names if kinds[name] != "data"]
    if routines:
        lines += [".. autosummary::", "   :nosignatures:", ""]
        lines += [f"   {name}" for name in routines]
        lines.append("")
    for name in routines:
        obj = getattr(module, name)
        real = f"{getattr(obj, '__module__', modname)}.{getattr(obj, '__qualname__', name)}"
        aliases[real] = f"{modname}.{name}"
        lines += [f".. {kinds[name]}:: {name}", ""]
    constants = [name for name in names if kinds[name] == "data"]
    if constants:
        lines += ["Constants", "---------", ""]
    for name in constants:
        lines += [f".. py:data:: {name}", ""]
        doc = _attr_doc(modname, name, getattr(module, name))
        lines += [f"   {line}" if line else "" for line in doc]
        lines.append("")
    extras = EXTRAS.get(modname, ())
    if extras:
        lines += [
            "Types returned by the names above",
            "---------------------------------",
            "",
            "Not imported from the package itself; shown here for their attributes and methods.",
            "",
        ]
    for real in extras:
        lines += [f".. autoclass:: {real}", ""]
    return "\n".join(lines), aliases


def index_page(homes: dict[str, str]) -> str:
    """api/index.rst: approxtree's own names, each linked to the page documenting it."""
    import approxtree

    lines = [
        "API reference",
        "=============",
        "",
        "Generated from the docstrings. ``import approxtree as at`` gives the names below;",
        "each is documented on the page of the subpackage that holds it.",
        "",
        ".. list-table::",
        "   :header-rows: 1",
        "   :widths: 30 70",
        "",
        "   * - ``approxtree``",
        "     - documented as",
    ]
    for name in approxtree.__all__:
        if name == "__version__":
            continue
        home = homes[name]
        lines += [f"   * - ``at.{name}``", f"     - :py:obj:`~{home}`"]
    lines += [
        "",
        "``approxtree.__version__`` is the installed version string.",
        "",
        "Subpackages and modules",
        "-----------------------",
        "",
        ".. list-table::",
        "   :widths: 30 70",
        "",
    ]
    for modname in PUBLIC:
        page = modname.removeprefix("approxtree.")
        lines += [f"   * - :doc:`{modname} <{page}>`", f"     - {BLURBS[modname]}"]
    lines += ["", ".. toctree::", "   :hidden:", ""]
    lines += [f"   {m.removeprefix('approxtree.')}" for m in PUBLIC]
    return "\n".join(lines) + "\n"


def _write(path: Path, text: str) -> None:
    # Unchanged pages keep their time stamp, so an incremental build does not reread them.
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def write_pages(app: Any) -> None:
    """builder-inited: write api/*.rst and remember the alias table for cross-references."""
    import approxtree

    folder = Path(app.srcdir) / "api"
    folder.mkdir(exist_ok=True)
    aliases: dict[str, str] = {}
    short: dict[str, set[str]] = {}
    for modname in PUBLIC:
        text, found = module_page(modname)
        _write(folder / f"{modname.removeprefix('approxtree.')}.rst", text)
        aliases.update(found)
        for public in found.values():
            short.setdefault(public.rsplit(".", 1)[1], set()).add(public)
    # approxtree.X and the real paths of approxtree's names point at their documented homes.
    homes: dict[str, str] = {}
    for name in approxtree.__all__:
        if name == "__version__":
            continue
        obj = getattr(approxtree, name)
        if inspect.ismodule(obj):
            # approxtree.verify is a function until the subpackage of that name is imported.
            obj = getattr(obj, name)
        real = f"{obj.__module__}.{obj.__qualname__}"
        if real in aliases:
            homes[name] = aliases[real]
        elif obj.__module__ in PUBLIC:
            homes[name] = f"{obj.__module__}.{name}"
        else:
            logger.warning("approxtree.%s is documented on no API page", name)
            homes[name] = real
        aliases[f"approxtree.{name}"] = homes[name]
    _write(folder / "index.rst", index_page(homes))
    app.env.approxtree_aliases = aliases
    app.env.approxtree_short = {k: next(iter(v)) for k, v in short.items() if len(v) == 1}


def resolve_alias(app: Any, env: Any, node: Any, contnode: Any) -> Any:
    """missing-reference: a real or top-level path, or a bare class name, to its public name."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"]
    aliases = getattr(env, "approxtree_aliases", {})
    new = None
    # The longest known prefix (methods and attributes of a class: Engine.render).
    head, tail = target, ""
    while head:
        if head in aliases:
            new = aliases[head] + tail
            break
        if "." not in head:
            break
        head, last = head.rsplit(".", 1)
        tail = f".{last}{tail}"
    if new is None:
        first, _, rest = target.partition(".")
        short = getattr(env, "approxtree_short", {})
        if first in short:
            new = short[first] + (f".{rest}" if rest else "")
    if new is None or new == target:
        return None
    domain = env.get_domain("py")
    return domain.resolve_xref(
        env, node["refdoc"], app.builder, node["reftype"], new, node, contnode
    )


def setup(app: Any) -> dict[str, Any]:
    app.connect("builder-inited", write_pages)
    app.connect("missing-reference", resolve_alias)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
