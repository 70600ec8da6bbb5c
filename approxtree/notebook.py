"""Terrains, trees and frames in a Jupyter notebook: PNG previews and an orbiting widget.

``repr_png(obj)`` is the PNG a notebook shows for a ``Frame`` (its image), an
``ApproximationTree`` (an overview rendered with an offscreen EGL Engine) or a terrain
(``GeometryData``: a quick coarse tree of it, then the same overview). The overview is
``framing_camera``'s fitted view from the south, 640 × 360 pixels, α = 2 px, the default
palette (a tint over the terrain's own range), sky background. Without an OpenGL context it
returns None, and Jupyter falls back to the text repr (a repr never raises).
``approxtree/__init__.py`` registers it with IPython's PNG formatter when imported inside
IPython, so the tree and terrain classes need not know about this module (imports point down:
notebook → viewer, render → tree). A Frame has its own ``_repr_png_``.

``TerrainWidget(tree)`` is a jupyter-rfb ``RemoteFrameBuffer``: each frame is rendered by an
Engine, a drag orbits (left button) or pans (right or middle button, or with Shift) and the
wheel zooms towards the target, through the viewer's ``OrbitController``. Needs the
``notebook`` extra (``pip install approxtree[notebook]``). A tree changed by
``tree.update(...)`` in a later cell is redrawn after that cell (IPython's post_run_cell
event: ``TerrainWidget.refresh``), the Engine keeping the unchanged nodes' meshes; so is a
re-baked pyramid given to ``TerrainWidget.set_textures``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from approxtree.errors import ApproxTreeError
from approxtree.render.camera import Camera
from approxtree.render.cut import Cut
from approxtree.render.engine import Engine
from approxtree.render.frame import Frame
from approxtree.render.frame_state import framing_camera
from approxtree.render.style import Style
from approxtree.viewer.controllers import OrbitController, to_camera, to_display

# The widget's base class comes with the ``notebook`` extra; without it the previews work and
# only TerrainWidget refuses.
try:
    from jupyter_rfb import RemoteFrameBuffer as _Base
except ImportError:  # pragma: no cover - the extra is installed in CI
    _Base = object

#: Size (w, h) of a preview image.
PREVIEW_SIZE = (640, 360)
#: α threshold (pixels) of previews and widget frames: a cheap cut, still without visible error.
PREVIEW_ALPHA = 2.0
#: ε of the quick tree of a terrain preview, as a share of its z range.
PREVIEW_EPSILON_SHARE = 0.005
#: Field of view (degrees) of previews and the widget.
FOV = 45.0
#: The style of the widget's frames: the default lighting in front of a sky.
SKY = Style(background="sky")


def frame_png(frame: Frame) -> bytes | None:
    """The PNG of a frame's (h, w, 4) image; None when the frame was not read back."""
    return frame._repr_png_()


def preview_tree(terrain: Any) -> Any:
    """A quick coarse ApproximationTree of a terrain for its preview: ε = 0.5 % of its z
    range (at least 1e-6), patches of at most 33 × 33 points."""
    from approxtree.tree import ApproximationTree

    lo, hi = terrain.z_range
    span = float(hi - lo) if math.isfinite(hi - lo) else 1.0
    return ApproximationTree.build(terrain, epsilon=max(1e-6, PREVIEW_EPSILON_SHARE * span))


def preview(
    tree: Any,
    size: tuple[int, int] = PREVIEW_SIZE,
    background: str = "sky",
    world_positions: bool = False,
    **engine_options: Any,
) -> Frame:
    """Render the fitted overview of a tree (``framing_camera``) with an offscreen Engine.

    Raises ContextUnavailableError without OpenGL (``repr_png`` turns that into None).
    world_positions: also fill the frame's world positions (``Engine.world_positions``).
    """
    with Engine(tree, **engine_options) as engine:
        camera = framing_camera(tree.bboxes[0], engine.scale, size, fov=FOV)
        frame = engine.render(camera, size, Cut(PREVIEW_ALPHA), style=Style(background=background))
        if world_positions:
            engine.world_positions(frame)
        return frame


def repr_png(obj: Any) -> bytes | None:
    """The notebook PNG of a Frame, a tree or a terrain; None when it cannot be drawn."""
    try:
        if isinstance(obj, Frame):
            return frame_png(obj)
        tree = obj if hasattr(obj, "bboxes") else preview_tree(obj)
        return frame_png(preview(tree))
    except Exception:
        # A repr never raises: Jupyter then shows the text repr.
        return None


class _OrbitView:
    """The widget's state without the widget: an Engine, an orbit pose and pointer events.

    events follow the jupyter_rfb event spec: dicts with "event_type" (pointer_down,
    pointer_move, pointer_up, wheel, resize), "x", "y", "button", "buttons", "modifiers",
    "dx", "dy", "width", "height".
    """

    def __init__(self, tree: Any, size: tuple[int, int], **engine_options: Any) -> None:
        self.tree = tree
        self.engine = Engine(tree, **engine_options)
        self.size = (int(size[0]), int(size[1]))
        home = framing_camera(tree.bboxes[0], self.engine.scale, self.size, fov=FOV)
        o, s = tree.origin, self.engine.scale
        self.orbit = OrbitController(to_display(home.eye, o, s), to_display(home.target, o, s))
        self._last: tuple[float, float] | None = None
        self.last_frame: Frame | None = None

    def camera(self) -> Camera:
        return to_camera(
            self.orbit.eye, self.orbit.target, self.tree.origin, self.engine.scale, FOV
        )

    def render(self) -> np.ndarray:
        """(h, w, 4) uint8 RGBA of the current pose."""
        frame = self.engine.render(self.camera(), self.size, Cut(PREVIEW_ALPHA), style=SKY)
        self.last_frame = frame
        # Rendered without a target, a frame is always read back.
        if frame.image is None:
            raise ApproxTreeError("The engine read back no image of the preview.")
        return frame.image

    def handle(self, event: dict[str, Any]) -> bool:
        """Apply one event; True when the picture changes."""
        kind = event.get("event_type") or event.get("type")
        if kind == "resize":
            w, h = int(event["width"]), int(event["height"])
            if w > 0 and h > 0 and (w, h) != self.size:
                self.size = (w, h)
                return True
            return False
        if kind == "pointer_down":
            self._last = (float(event["x"]), float(event["y"]))
            return False
        if kind == "pointer_up":
            self._last = None
            return False
        if kind == "pointer_move" and self._last is not None:
            x, y = float(event["x"]), float(event["y"])
            dx, dy = x - self._last[0], y - self._last[1]
            self._last = (x, y)
            buttons = tuple(event.get("buttons", ()))
            if 2 in buttons or 3 in buttons or "Shift" in tuple(event.get("modifiers", ())):
                self.orbit.pan(dx, dy, self.size[1], FOV)
            else:
                self.orbit.orbit(dx, dy)
            return True
        if kind == "wheel":
            # One wheel notch (about 100 units) zooms by 10 % towards the target.
            self.orbit.zoom_to(self.orbit.target, 1.1 ** (float(event.get("dy", 0.0)) / 100.0))
            return True
        return False

    def close(self) -> None:
        self.engine.release()


class TerrainWidget(_Base):
    """An interactive view of ``tree`` (a tree, or a terrain previewed by a quick tree) in a
    notebook: drag to orbit, right-drag or Shift-drag to pan, wheel to zoom.

    A jupyter_rfb RemoteFrameBuffer whose frames the Engine renders; engine_options: keywords
    of ``Engine`` (textures, exaggeration, palette...); ``view`` holds the Engine and the
    orbit pose. Needs jupyter-rfb (the ``notebook`` extra) and an OpenGL context.
    """

    def __init__(
        self, tree: Any, size: tuple[int, int] = PREVIEW_SIZE, **engine_options: Any
    ) -> None:
        if _Base is object:
            from approxtree.errors import InvalidParameterError

            raise InvalidParameterError(
                "The notebook widget needs jupyter-rfb: pip install 'approxtree[notebook]'."
            )
        if not hasattr(tree, "bboxes"):
            tree = preview_tree(tree)
        # The view first: the widget may ask for a frame as soon as it exists.
        self.view = _OrbitView(tree, size, **engine_options)
        super().__init__(css_width=f"{size[0]}px", css_height=f"{size[1]}px")
        # After each cell: redraw when the cell updated the tree.
        self._ipython = _ipython()
        if self._ipython is not None:
            self._ipython.events.register("post_run_cell", self._after_cell)

    def refresh(self) -> bool:
        """Redraw when the tree was updated since the last frame; True when it was."""
        if not self.view.engine.tree_changed:
            return False
        self.request_draw()
        return True

    def set_textures(self, textures: Any) -> None:
        """Drape ``textures`` (``Engine.set_textures``: after a re-bake of the same pyramid,
        only the texture patches of re-baked tiles are loaded again) and redraw."""
        self.view.engine.set_textures(textures)
        self.request_draw()

    def _after_cell(self, *args: Any) -> None:
        self.refresh()

    def get_frame(self) -> np.ndarray:
        """(h, w, 4) uint8 RGBA of the current pose (jupyter_rfb asks for it to draw)."""
        return self.view.render()

    def handle_event(self, event: dict[str, Any]) -> None:
        if self.view.handle(event):
            self.request_draw()

    def close(self, *args: Any, **kwargs: Any) -> None:
        if self._ipython is not None:
            self._ipython.events.unregister("post_run_cell", self._after_cell)
            self._ipython = None
        self.view.close()
        super().close(*args, **kwargs)


def _ipython() -> Any:
    """The running IPython shell, or None (a plain Python process)."""
    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover - IPython comes with the notebook extra
        return None
    return get_ipython()
