"""OpenGL contexts: a standalone headless one through EGL, and the limits of any context.

The only place that creates a context. The Engine makes one when it is given none; baking
(textures/gl_bake.py) never makes its own: its callers (the CLI's ``bake`` and ``demo``) create
one here and pass it in, so the textures room imports nothing from render (DESIGN.md,
"Package layout"). A context that cannot be made is a ContextUnavailableError whose message
names the packages to install (``INSTALL_HINT``).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from approxtree.errors import ContextUnavailableError, InvalidParameterError
from approxtree.render.frame_state import check_viewport

#: What to install (or pass) when no OpenGL context can be made.
INSTALL_HINT = (
    "Install the EGL and Mesa OpenGL drivers (Debian/Ubuntu: apt-get install -y libegl1 "
    "libgl1-mesa-dri; Fedora: dnf install mesa-libEGL mesa-dri-drivers), or pass a context "
    "of your own with Engine(tree, context=ctx)."
)
#: Limits assumed when a driver does not report them.
_DEFAULT_LIMIT = 16384


def create_context() -> Any:
    """A standalone headless OpenGL 3.3+ moderngl context through EGL, or
    ContextUnavailableError (with ``INSTALL_HINT``). The caller releases it."""
    try:
        import moderngl

        ctx = moderngl.create_standalone_context(backend="egl")  # type: ignore[arg-type]
    except Exception as exc:
        raise ContextUnavailableError(
            f"No OpenGL context could be created through EGL ({exc}). {INSTALL_HINT}"
        ) from exc
    if ctx.version_code < 330:
        version = ctx.version_code
        ctx.release()
        raise ContextUnavailableError(
            f"OpenGL 3.3 or newer is needed, the EGL context offers {version}. {INSTALL_HINT}"
        )
    return ctx


#: Renderer names of Mesa's and Google's CPU rasterizers (GL_RENDERER).
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "swiftshader")


def is_software(ctx: Any) -> bool:
    """Whether ``ctx`` draws on the CPU (Mesa llvmpipe, softpipe, SwiftShader)."""
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(name in renderer for name in SOFTWARE_RENDERERS)


@functools.cache
def hardware_gl() -> bool:
    """Whether this process can make a context that draws on a GPU (not ``is_software``);
    asked once per process."""
    try:
        ctx = create_context()
    except ContextUnavailableError:
        return False
    try:
        return not is_software(ctx)
    finally:
        ctx.release()


@contextmanager
def optional_context(wanted: bool = True) -> Iterator[Any]:
    """A standalone context for a ``with`` block (released after it), or None when not
    ``wanted`` or when none can be made (callers then fall back to the CPU, e.g. bake)."""
    ctx = None
    if wanted:
        try:
            ctx = create_context()
        except ContextUnavailableError:
            ctx = None
    try:
        yield ctx
    finally:
        if ctx is not None:
            ctx.release()


def check_size(ctx: Any, size: tuple[int, int]) -> tuple[int, int]:
    """``size`` (w, h) as whole pixels within ``ctx``'s limits, or InvalidParameterError."""
    w, h = check_viewport(size)
    limit = max_viewport(ctx)
    if w > limit[0] or h > limit[1]:
        raise InvalidParameterError(
            f"size {w} × {h} exceeds this OpenGL's limit of {limit[0]} × {limit[1]} pixels."
        )
    return w, h


def max_viewport(ctx: Any) -> tuple[int, int]:
    """(w, h): the largest framebuffer ``ctx`` draws (viewport and renderbuffer limits)."""
    dims = ctx.info.get("GL_MAX_VIEWPORT_DIMS", (_DEFAULT_LIMIT, _DEFAULT_LIMIT))
    rb = int(ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", _DEFAULT_LIMIT))
    return min(int(dims[0]), rb), min(int(dims[1]), rb)


def max_texture_size(ctx: Any, default: int = _DEFAULT_LIMIT) -> int:
    """GL_MAX_TEXTURE_SIZE of ``ctx`` (``default`` when the driver does not say)."""
    return int(ctx.info.get("GL_MAX_TEXTURE_SIZE", default))
