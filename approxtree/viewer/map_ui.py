"""The viewer's map interface, drawn with imgui each frame: the "Map" panel (cursor readout,
measure, sun, exaggeration, lighting, bookmarks, statistics), the legend, the scale bar and
the north arrow.

``draw`` returns the screen boxes of what it drew (image pixels: x0, y0, x1, y1 from the
top-left corner) so scripted runs and tests can find them in screenshots.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.textures.thematic import LEGENDS, ClassTable
from approxtree.viewer.map_tools import format_length, north_angle, scale_bar
from approxtree.viewer.parts import ViewerParts
from approxtree.viewer.settings import LIGHTING_MODES

#: Scale bar: longest length (pixels), margin to the window's corner, box height (pixels).
BAR_PX, MARGIN, BAR_BOX_H = 160.0, 16.0, 34.0
#: North arrow: radius (pixels) of its disc.
ARROW_R = 24.0
#: Legend: stops of the hypsometric legend, swatch size (pixels).
LEGEND_STOPS, SWATCH = 6, 14.0


def _col(r: float, g: float, b: float, a: float = 1.0) -> int:
    from imgui_bundle import imgui

    return imgui.get_color_u32(imgui.ImVec4(r, g, b, a))


def check_legend(legend: str | None) -> None:
    """A legend name is one of textures/thematic.py's LEGENDS (or None)."""
    if legend is not None and legend not in LEGENDS:
        raise InvalidParameterError(
            f"Unknown legend {legend!r}; choose one of {', '.join(LEGENDS)}."
        )


class MapUI:
    """Draws the map interface of ``viewer`` with imgui (between its new_frame and render)."""

    def __init__(self, viewer: ViewerParts) -> None:
        self.viewer = viewer
        self.unit = "m"

    def draw(
        self, fs: Any, stats: dict[str, Any], size: tuple[int, int], panel: bool = True
    ) -> dict[str, Any]:
        """Draw the map furniture (scale bar, north arrow, measured line, legend) and, with
        ``panel``, the Map panel; returns their boxes."""
        from imgui_bundle import imgui

        v = self.viewer
        boxes: dict[str, Any] = {}
        w, h = size
        target = v.nav.pose_world()[1]
        unit_scale = v.map.unit_scale
        # 1. Scale bar, bottom-left: the nicest length that fits BAR_PX at the view's target.
        length, px = scale_bar(fs, target, unit_scale, BAR_PX)
        dl = imgui.get_background_draw_list()
        x0, y1 = MARGIN, h - MARGIN
        box = [x0, y1 - BAR_BOX_H, x0 + BAR_PX + 12.0, y1]
        dl.add_rect_filled(
            imgui.ImVec2(box[0], box[1]), imgui.ImVec2(box[2], box[3]), _col(1, 1, 1, 0.75), 4.0
        )
        if px > 0:
            bx0, by = x0 + 6.0, y1 - 8.0
            half = px / 2.0
            dl.add_rect_filled(
                imgui.ImVec2(bx0, by - 5), imgui.ImVec2(bx0 + half, by), _col(0, 0, 0)
            )
            dl.add_rect_filled(
                imgui.ImVec2(bx0 + half, by - 5), imgui.ImVec2(bx0 + px, by), _col(1, 1, 1)
            )
            dl.add_rect(
                imgui.ImVec2(bx0, by - 5), imgui.ImVec2(bx0 + px, by), _col(0, 0, 0), 0.0, 1.0
            )
            dl.add_text(
                imgui.ImVec2(bx0, box[1] + 3.0), _col(0, 0, 0), format_length(length, self.unit)
            )
        boxes["scale_bar"] = box
        boxes["scale_length"], boxes["scale_px"] = length, px
        # 2. North arrow above it: a disc with a two-tone needle turned to north on screen.
        angle = north_angle(fs, target, unit_scale)
        cx, cy = MARGIN + ARROW_R + 4.0, box[1] - 10.0 - ARROW_R
        dl.add_circle_filled(imgui.ImVec2(cx, cy), ARROW_R, _col(1, 1, 1, 0.75), 32)
        a = math.radians(angle)
        ux, uy = math.sin(a), -math.cos(a)  # screen y down
        tip = imgui.ImVec2(cx + ux * (ARROW_R - 4), cy + uy * (ARROW_R - 4))
        tail = imgui.ImVec2(cx - ux * (ARROW_R - 4), cy - uy * (ARROW_R - 4))
        left = imgui.ImVec2(cx - uy * 7.0, cy + ux * 7.0)
        right = imgui.ImVec2(cx + uy * 7.0, cy - ux * 7.0)
        dl.add_triangle_filled(tip, left, right, _col(0.85, 0.1, 0.1))
        dl.add_triangle_filled(tail, right, left, _col(0.25, 0.25, 0.25))
        boxes["north_arrow"] = [cx - ARROW_R, cy - ARROW_R, cx + ARROW_R, cy + ARROW_R]
        boxes["north_deg"] = angle
        # 3. The measured line, between the projected points.
        m = v.map.measure_points
        if m:
            pts, wv = fs.world_to_pixels(np.asarray(m))
            if np.all(wv > 0):
                scr = [imgui.ImVec2(p[0], h - p[1]) for p in pts]
                for p in scr:
                    dl.add_circle_filled(p, 4.0, _col(1, 0.9, 0.1))
                if len(scr) == 2:
                    dl.add_line(scr[0], scr[1], _col(1, 0.9, 0.1), 2.0)
        # 4. Legend window, bottom-right.
        boxes["legend"] = self._legend(w, h)
        # 5. The Map panel, top-left (not in a screenshot that keeps the furniture only).
        if panel:
            self._panel(stats)
        return boxes

    # -- legend --------------------------------------------------------------------------------

    def _legend(self, w: float, h: float) -> list[float]:
        from imgui_bundle import imgui

        imgui.set_next_window_pos(
            imgui.ImVec2(w - MARGIN, h - MARGIN), imgui.Cond_.always, imgui.ImVec2(1, 1)
        )
        flags = imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_focus_on_appearing
        imgui.begin("Legend", None, flags)
        entries = self.legend_entries()
        if entries["kind"] == "classes":
            imgui.text(entries["title"])
            for name, rgb in entries["items"]:
                self._swatch(rgb)
                imgui.same_line()
                imgui.text(name)
        else:
            imgui.text(entries["title"])
            for z, rgb in entries["items"]:
                self._swatch(rgb)
                imgui.same_line()
                imgui.text(f"{z:,.0f} {self.unit}")
        p, s = imgui.get_window_pos(), imgui.get_window_size()
        imgui.end()
        return [p.x, p.y, p.x + s.x, p.y + s.y]

    def legend_entries(self) -> dict[str, Any]:
        """What the legend shows: the thematic layer's classes (its legend name) when it is
        drawn, a note when a coloured layer has no legend named, else (untextured or baked
        shading only) the hypsometric palette's colours at LEGEND_STOPS elevations."""
        v = self.viewer
        s = v.settings
        if v.pyramids and s.thematic and v.legend is not None:
            table = ClassTable.legend(v.legend)
            items = [
                (label, tuple(int(c) for c in table.colours[k][:3]))
                for k, (label, _) in LEGENDS[v.legend].items()
                if k in table.colours
            ]
            return {"kind": "classes", "title": v.legend, "items": items}
        if v.pyramids and s.thematic and v.driver.colour_layer:
            # A coloured layer whose legend was not named: the palette would mislead.
            return {
                "kind": "classes",
                "title": "colours of the texture layer (name a legend: --legend)",
                "items": [],
            }
        z0, z1 = v.map.terrain.z_range
        zs = np.linspace(z1, z0, LEGEND_STOPS)
        palette = v.driver.palette
        rgb = palette.colours(zs, (z0, z1))
        stops: list[tuple[float, tuple[int, ...]]] = [
            (float(z), tuple(round(255 * c) for c in col[:3]))
            for z, col in zip(zs, rgb, strict=True)
        ]
        return {"kind": "palette", "title": f"elevation ({palette.name})", "items": stops}

    @staticmethod
    def _swatch(rgb: tuple[int, int, int]) -> None:
        from imgui_bundle import imgui

        p = imgui.get_cursor_screen_pos()
        imgui.get_window_draw_list().add_rect_filled(
            p, imgui.ImVec2(p.x + SWATCH, p.y + SWATCH), _col(*(c / 255.0 for c in rgb))
        )
        imgui.dummy(imgui.ImVec2(SWATCH, SWATCH))

    # -- the Map panel --------------------------------------------------------------------

    def _panel(self, stats: dict[str, Any]) -> None:
        from imgui_bundle import imgui

        v = self.viewer
        s = v.settings
        imgui.set_next_window_pos(imgui.ImVec2(MARGIN, MARGIN), imgui.Cond_.first_use_ever)
        imgui.set_next_window_bg_alpha(0.75)
        # Sized to its content: the measure section and bookmarks come and go.
        imgui.begin("Map", None, imgui.WindowFlags_.always_auto_resize)
        imgui.push_item_width(120.0)
        r = v.map.cursor_readout
        crs = v.map.terrain.crs or "no CRS"
        if r is None:
            imgui.text("cursor: off the terrain")
        else:
            # Degrees need more digits than metres for the same precision on the ground.
            digits = 6 if v.map.unit_scale[0] != 1.0 else 2
            imgui.text(f"x {r.x:,.{digits}f}  y {r.y:,.{digits}f}")
            imgui.text_disabled(crs[:40])
            if r.lon is not None:
                imgui.text(f"lon {r.lon:.5f}  lat {r.lat:.5f}")
            imgui.text(f"elevation {r.elevation:,.2f} {self.unit}")
            if r.z_drawn is not None:
                imgui.text_disabled(f"(drawn {r.z_drawn:,.2f})")
        imgui.separator()
        if imgui.checkbox("measure (M)", s.tool == "measure")[0]:
            v.do("measure")
        if v.map.measurement is not None:
            m = v.map.measurement
            imgui.text(f"horizontal {format_length(round(m['horizontal'], 2), self.unit)}")
            imgui.text(f"3-D {format_length(round(m['distance_3d'], 2), self.unit)}")
            z = np.asarray(m["profile_z"], dtype=np.float32)
            imgui.plot_lines("##profile", z, graph_size=imgui.ImVec2(240, 50))
            imgui.text_disabled(str(m["profile"])[-40:])
        imgui.separator()
        changed, az = imgui.slider_float("sun azimuth", s.sun_azimuth, 0.0, 360.0, "%.0f deg")
        if changed:
            s.sun_azimuth = az
        changed, alt = imgui.slider_float("sun altitude", s.sun_altitude, 1.0, 90.0, "%.0f deg")
        if changed:
            s.sun_altitude = alt
        changed, k = imgui.slider_float("exaggeration", s.exaggeration, 0.25, 20.0, "x%.2f")
        if changed:
            v.set_exaggeration(k)
        modes = list(LIGHTING_MODES)
        changed, i = imgui.combo("lighting (H)", modes.index(s.lighting), modes)
        if changed:
            s.lighting = modes[i]
        imgui.separator()
        if imgui.button("save view (B)"):
            v.do("bookmark")
        for name in v.map.bookmarks.names():
            if imgui.button(f"fly to##{name}"):
                v.map.fly_to(name)
            imgui.same_line()
            imgui.text(name)
        if imgui.collapsing_header("statistics"):
            imgui.text(
                f"triangles {stats.get('triangles', 0):,}  patches {stats.get('patches', 0):,}"
            )
            imgui.text(f"max alpha {stats.get('max_alpha', 0):.2f} px (<= {s.alpha:.2f})")
            imgui.text(f"max gamma {stats.get('max_gamma', 0):.2f} px2 (<= {s.gamma:.2f})")
            imgui.text(
                f"paged uploads {stats.get('paged_uploads', 0)}  "
                f"pending {stats.get('pending', 0)}  stand-ins {stats.get('stand_ins', 0)}"
            )
            imgui.text(f"{'fly' if s.fly else 'orbit'}  frozen {s.frozen}  wireframe {s.wireframe}")
        for line in v.messages[-3:]:
            imgui.text_wrapped(line)
        imgui.pop_item_width()
        imgui.end()
