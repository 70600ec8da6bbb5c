"""Interface: the imgui layer drawn over the terrain each frame.

One imgui frame per viewer frame, always begun and ended so imgui's state stays consistent
while the interface is hidden: the map interface (map_ui.MapUI: panel, legend, scale bar,
north arrow) and the help overlay (F1), when shown. ``draw`` returns the screen boxes of what
was drawn, for the stats lines.
"""

from __future__ import annotations

from typing import Any

from approxtree.viewer.imgui_renderer import ImguiRenderer
from approxtree.viewer.keys import help_lines
from approxtree.viewer.map_ui import MapUI
from approxtree.viewer.parts import ViewerParts


class Interface:
    """The imgui renderer (``gui``, which also takes the mouse events) and what ``viewer``
    shows with it."""

    def __init__(self, viewer: ViewerParts) -> None:
        self.viewer = viewer
        self.gui = ImguiRenderer(viewer.window.ctx, viewer.window.size())
        self.map_ui = MapUI(viewer)

    def draw(
        self,
        frame_state: Any,
        stats: dict[str, Any],
        size: tuple[int, int],
        dt: float,
        furniture_only: bool = False,
    ) -> dict[str, Any]:
        """Draw one imgui frame over the terrain of ``frame_state`` (framebuffer ``size``)
        into the window; returns the boxes drawn (empty while the interface is hidden).
        furniture_only: the map furniture (legend, scale bar, north arrow) without the
        panels, even while the interface is hidden (a screenshot that keeps it)."""
        from imgui_bundle import imgui

        v = self.viewer
        self.gui.new_frame(v.window.size(), dt)
        boxes: dict[str, Any] = {}
        if (v.settings.ui or furniture_only) and frame_state is not None:
            boxes = self.map_ui.draw(frame_state, stats, size, panel=not furniture_only)
            if v.settings.help and not furniture_only:
                imgui.begin("Keys (F1)")
                for line in help_lines():
                    imgui.text(line)
                imgui.end()
        v.window.ctx.fbo.use()
        self.gui.render(size)
        return boxes

    def release(self) -> None:
        self.gui.release()
