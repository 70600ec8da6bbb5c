"""Rendering: camera, frame state, visual errors, selection (pure) and the moderngl Engine.

Only this package touches OpenGL, and only inside the Renderer (renderer.py) an ``Engine``
owns, always through a context passed in or created by the Engine. The selection modules
(camera, frame_state, frustum, visual_error, selector, traversal) import no GL and can be used
without a GPU; the provider (provider.py) loads node payloads on background threads.
"""

from approxtree.render.camera import Camera, Projection
from approxtree.render.frame_state import (
    FrameState,
    display_scale,
    framing_camera,
    overview_camera,
)
from approxtree.render.selector import Selection, SelectionResult, select
from approxtree.render.style import Background, Sun
from approxtree.render.traversal import Cut
from approxtree.render.visual_error import texel_sizes, visual_errors


def __getattr__(name: str):
    # The Engine imports moderngl: load it on first use so selection stays GL-free.
    if name in ("Engine", "Frame"):
        from approxtree.render import engine

        return getattr(engine, name)
    raise AttributeError(f"module 'approxtree.render' has no attribute {name!r}")


__all__ = [
    "Background",
    "Camera",
    "Cut",
    "Engine",
    "Frame",
    "FrameState",
    "Projection",
    "Selection",
    "SelectionResult",
    "Sun",
    "display_scale",
    "framing_camera",
    "overview_camera",
    "select",
    "texel_sizes",
    "visual_errors",
]
