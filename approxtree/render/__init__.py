"""Rendering: camera, frame state, visual errors, selection (pure), tile sources and the Engine.

Only this package touches OpenGL, and only inside the Renderer (renderer.py) an ``Engine``
owns, always through a context passed in or created by context.py. The selection modules
(camera, frame_state, frustum, visual_error, selector, traversal, cut) import no GL and can be
used without a GPU; the tile sources (source.py) select and load what each kind of tree draws,
the provider (provider.py) loads node payloads on background threads.

A frame: ``Engine(tree).render(camera, size, Cut(alpha=1.0, gamma=2.0), style=Style(...),
paging=Paging(...))``.
"""

from approxtree.render.camera import Camera, Projection
from approxtree.render.cut import Cut
from approxtree.render.frame import Frame
from approxtree.render.frame_state import (
    FrameState,
    display_scale,
    framing_camera,
    overview_camera,
)
from approxtree.render.selector import Selection, SelectionResult, select
from approxtree.render.style import Background, Style, Sun
from approxtree.render.traversal import Paging
from approxtree.render.visual_error import texel_sizes, visual_errors


def __getattr__(name: str):
    # The Engine imports moderngl: load it on first use so selection stays GL-free.
    if name == "Engine":
        from approxtree.render import engine

        return engine.Engine
    raise AttributeError(f"module 'approxtree.render' has no attribute {name!r}")


__all__ = [
    "Background",
    "Camera",
    "Cut",
    "Engine",
    "Frame",
    "FrameState",
    "Paging",
    "Projection",
    "Selection",
    "SelectionResult",
    "Style",
    "Sun",
    "display_scale",
    "framing_camera",
    "overview_camera",
    "select",
    "texel_sizes",
    "visual_errors",
]
