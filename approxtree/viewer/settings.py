"""ViewSettings: what the keys and the Map panel change, shared by the viewer's parts."""

from __future__ import annotations

from dataclasses import dataclass

#: The lighting modes H cycles through (Engine.render's ``lighting``).
LIGHTING_MODES = ("auto", "on", "off")


@dataclass
class ViewSettings:
    """What the keys and the panel change. alpha: px; gamma: px²; exaggeration: z factor;
    lighting: "auto", "on" or "off"; sun: degrees; ui: the map interface shown; tool: the
    active map tool ("measure") or None; furniture_in_shots: screenshots (P, --screenshots)
    keep the map furniture (legend, scale bar, north arrow), not the panels."""

    alpha: float = 1.0
    gamma: float = 2.0
    wireframe: bool = False
    skirts: bool = True
    exaggeration: float = 1.0
    thematic: bool = True
    texture_index: int = 0
    lighting: str = "auto"
    frozen: bool = False
    help: bool = False
    fly: bool = False
    sun_azimuth: float = 315.0
    sun_altitude: float = 45.0
    ui: bool = True
    tool: str | None = None
    furniture_in_shots: bool = False
