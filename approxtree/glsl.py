"""Shader loader: GLSL programs from ``shaders/*.glsl`` (installed as ``approxtree.shaders``).

A program file starts with ``#version`` on line 1 and holds its stages in
``#if defined VERTEX_SHADER … #elif defined FRAGMENT_SHADER … #endif`` sections (a
``GEOMETRY_SHADER`` section is compiled when present). For each stage the loader:

1. checks the ``#version`` line;
2. resolves ``#include "path"`` (relative to the shader folder), at most ``MAX_INCLUDE_DEPTH``
   deep, surrounding each included file with ``#line`` directives (source-string numbers index
   ``ShaderSource.files``) so compiler messages point at the real file and line;
3. inserts ``#define <STAGE>`` and ``#line 2 0`` right after the version line.

``ATTRIBUTES`` is the one registry of vertex attribute names: buffers are laid out from it and
every program's active attributes are checked against it.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from approxtree.errors import ApproxTreeError

#: Vertex attribute registry: role → (GLSL name, moderngl buffer format).
ATTRIBUTES: dict[str, tuple[str, str]] = {
    "position": ("in_position", "3f"),
    "skirt": ("in_skirt", "1f"),
}
#: Interleaved layout of terrain vertex buffers, in registry order: (format, *names).
VERTEX_LAYOUT: tuple[str, ...] = (
    " ".join(fmt for _, fmt in ATTRIBUTES.values()),
    *(name for name, _ in ATTRIBUTES.values()),
)
#: Bytes per vertex of VERTEX_LAYOUT (3 + 1 float32).
VERTEX_BYTES = 16

MAX_INCLUDE_DEPTH = 8
STAGES = ("VERTEX_SHADER", "GEOMETRY_SHADER", "FRAGMENT_SHADER")
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$')


class ShaderError(ApproxTreeError):
    """A shader file is missing, malformed, or fails to compile (message names file and line)."""


def shader_dir() -> Path:
    """The folder holding the .glsl files (inside the installed package)."""
    try:
        return Path(str(resources.files("approxtree.shaders")))
    except ModuleNotFoundError:
        # A source checkout imported through PYTHONPATH, without an install mapping shaders/
        # to approxtree.shaders (the editable install's own warm-up runs that way).
        source = Path(__file__).resolve().parent.parent / "shaders"
        if source.is_dir():
            return source
        raise ShaderError(
            "approxtree's shaders are missing: reinstall approxtree (pip install .)"
        ) from None


@dataclass(frozen=True)
class ShaderSource:
    """The stage sources of one program. files: source-string number → file name."""

    name: str
    stages: dict[str, str]
    files: tuple[str, ...]


def _read(path: Path) -> str:
    if not path.is_file():
        raise ShaderError(f"Shader file {path} not found; reinstall approxtree.")
    return path.read_text(encoding="utf-8")


def _expand(text: str, file_no: int, files: list[str], root: Path, depth: int) -> str:
    """``text`` with every #include replaced by the file's text between #line directives."""
    out = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        m = _INCLUDE.match(line)
        if not m:
            out.append(line)
            continue
        if depth >= MAX_INCLUDE_DEPTH:
            raise ShaderError(
                f"{files[file_no]}:{line_no}: #include nested deeper than {MAX_INCLUDE_DEPTH} "
                "(an include cycle?)."
            )
        rel = m.group(1)
        files.append(rel)
        child_no = len(files) - 1
        body = _expand(_read(root / rel), child_no, files, root, depth + 1)
        out.append(f"#line 1 {child_no}")
        out.append(body)
        out.append(f"#line {line_no + 1} {file_no}")
    return "\n".join(out)


def load_source(name: str, root: Path | None = None, defines: Sequence[str] = ()) -> ShaderSource:
    """Read ``<name>.glsl`` and build the source of each stage it defines; ``defines``: macro
    names defined in every stage (a program's variants, ``#if defined NAME``)."""
    root = shader_dir() if root is None else root
    text = _read(root / f"{name}.glsl")
    first, _, rest = text.partition("\n")
    if not first.startswith("#version"):
        raise ShaderError(
            f"{name}.glsl: line 1 must be the #version directive, got {first[:40]!r}."
        )
    files = [f"{name}.glsl"]
    body = _expand(rest, 0, files, root, 0)
    stages = {}
    for stage in STAGES:
        if re.search(rf"defined\s*\(?\s*{stage}\b", text):
            # Line 2 of the file follows the injected define.
            head = "".join(f"#define {d}\n" for d in (stage, *defines))
            stages[stage] = f"{first}\n{head}#line 2 0\n{body}\n"
    if "VERTEX_SHADER" not in stages or "FRAGMENT_SHADER" not in stages:
        raise ShaderError(f"{name}.glsl needs a VERTEX_SHADER and a FRAGMENT_SHADER section.")
    return ShaderSource(name, stages, tuple(files))


def create_program(
    ctx: Any, name: str, root: Path | None = None, defines: Sequence[str] = ()
) -> Any:
    """Compile ``<name>.glsl`` into a moderngl Program on ``ctx`` (``defines``: its variant's
    macro names, see ``load_source``).

    Compiler messages are re-raised as ShaderError, prefixed with the source-file table so
    ``0:12`` style locations can be read back.
    """
    src = load_source(name, root, defines)
    try:
        program = ctx.program(
            vertex_shader=src.stages["VERTEX_SHADER"],
            geometry_shader=src.stages.get("GEOMETRY_SHADER"),
            fragment_shader=src.stages["FRAGMENT_SHADER"],
        )
    except Exception as exc:
        table = ", ".join(f"{i} = {f}" for i, f in enumerate(src.files))
        raise ShaderError(f"Shader program {name} failed to build (files: {table}): {exc}") from exc
    known = {n for n, _ in ATTRIBUTES.values()}
    active = {k for k in program if type(program[k]).__name__ == "Attribute"}
    unknown = active - known
    if unknown:
        program.release()
        raise ShaderError(
            f"{name}.glsl uses vertex attributes {sorted(unknown)} missing from ATTRIBUTES."
        )
    return program
