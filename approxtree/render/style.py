"""Cartographic style of a frame: the sun, the background, the side-wall colour, lighting.

These are render-time settings: none of them changes the selection (the exaggeration, which
does, is the Engine's display scale; the palette is the Engine's too, uploaded once). The
shaders get them as uniforms. ``Style`` carries a frame's settings into ``Engine.render``.

- ``Style``: lighting, sun, background and wireframe of one frame, validated when made.

- ``Sun``: azimuth (degrees clockwise from north) and altitude (degrees above the horizon) of
  the light, in display coordinates (x east, y north, z up, z already exaggerated), the
  convention of gdaldem's hillshade.
- ``Background``: "transparent" (alpha 0 where no terrain is drawn), "sky" (a vertical gradient,
  pale at the horizon) or one opaque colour (a name, "#rrggbb" or an (r, g, b) tuple).
- ``WALL_COLOUR``: the neutral colour of the walls along the terrain's outer border, lit by the
  sun from their own (geometric) normal, never textured.
- ``resolve_lighting``: "auto" lights untextured terrain only: a texture pyramid whose shading
  was baked is drawn once, as it is (decal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from approxtree.errors import InvalidParameterError

#: Side walls along the terrain's outer border: a neutral warm grey (linear RGB in [0, 1]).
WALL_COLOUR = (0.62, 0.60, 0.57)
#: Sky gradient: colour at the top of the image and at its bottom (towards the horizon).
SKY_TOP = (0.42, 0.62, 0.85)
SKY_HORIZON = (0.86, 0.91, 0.96)
#: Colour names accepted by Background (besides "#rrggbb").
COLOUR_NAMES = {
    "white": (1.0, 1.0, 1.0),
    "black": (0.0, 0.0, 0.0),
    "grey": (0.5, 0.5, 0.5),
    "gray": (0.5, 0.5, 0.5),
    "paper": (0.96, 0.95, 0.92),
}
LIGHTING_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class Sun:
    """The light: azimuth in degrees clockwise from north, altitude in degrees above the
    horizon (0 < altitude <= 90). The default is the cartographic convention (north-west, 45°)."""

    azimuth: float = 315.0
    altitude: float = 45.0

    def __post_init__(self) -> None:
        for name in ("azimuth", "altitude"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise InvalidParameterError(f"Sun {name} must be a finite number, got {v!r}.")
        if not 0.0 < self.altitude <= 90.0:
            raise InvalidParameterError(
                f"Sun altitude must be in (0, 90] degrees above the horizon, got {self.altitude}."
            )

    @property
    def direction(self) -> np.ndarray:
        """(3,) unit vector towards the sun in display coordinates (x east, y north, z up)."""
        az, alt = math.radians(self.azimuth), math.radians(self.altitude)
        return np.array([math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)])


def as_sun(sun: Sun | tuple[float, float] | None) -> Sun:
    """``sun`` as a Sun: a Sun, (azimuth, altitude), or None for the default."""
    if sun is None:
        return Sun()
    if isinstance(sun, Sun):
        return sun
    try:
        az, alt = sun
    except (TypeError, ValueError):
        raise InvalidParameterError(
            f"sun must be a Sun or (azimuth, altitude) in degrees, got {sun!r}."
        ) from None
    return Sun(float(az), float(alt))


@dataclass(frozen=True)
class Background:
    """What the image shows where no terrain is drawn.

    kind: "transparent", "sky" or "colour"; colour: (r, g, b) in [0, 1] for "colour".
    """

    kind: str = "transparent"
    colour: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def parse(cls, value: Background | str | tuple | None) -> Background:
        """A Background from "transparent", "sky", a colour name, "#rrggbb", or (r, g, b) in
        [0, 1] (or 0..255 integers); None is transparent."""
        if value is None:
            return cls()
        if isinstance(value, Background):
            return value
        if isinstance(value, tuple | list):
            rgb = tuple(float(v) for v in value)
            if len(rgb) != 3:
                raise InvalidParameterError(f"A background colour is (r, g, b), got {value!r}.")
            if any(v > 1.0 for v in rgb):
                rgb = tuple(v / 255.0 for v in rgb)
            return cls("colour", _in_unit(rgb, value))
        text = str(value).strip().lower()
        if text in ("transparent", "sky"):
            return cls(text)
        if text in COLOUR_NAMES:
            return cls("colour", COLOUR_NAMES[text])
        hexa = text[1:] if text.startswith("#") else text
        if len(hexa) == 6:
            try:
                rgb = tuple(int(hexa[i : i + 2], 16) / 255.0 for i in (0, 2, 4))
                return cls("colour", rgb)  # type: ignore[arg-type]
            except ValueError:
                pass
        raise InvalidParameterError(
            f"Unknown background {value!r}: use sky, transparent, a colour name "
            f"({', '.join(COLOUR_NAMES)}) or #rrggbb."
        )

    @property
    def opaque(self) -> bool:
        return self.kind != "transparent"

    @property
    def colours(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(top colour, bottom colour) of the gradient the background pass draws."""
        if self.kind == "sky":
            return SKY_TOP, SKY_HORIZON
        return self.colour, self.colour


def _in_unit(rgb: tuple[float, ...], value: object) -> tuple[float, float, float]:
    if not all(0.0 <= v <= 1.0 for v in rgb):
        raise InvalidParameterError(f"Background colour channels must lie in [0, 1], got {value}.")
    return rgb  # type: ignore[return-value]


def resolve_lighting(lighting: bool | str | None, textured: bool) -> bool:
    """Whether the light modulates the colour: True/"on", False/"off", or "auto"/None: only
    for untextured terrain (baked shading is drawn once)."""
    if isinstance(lighting, bool):
        return lighting
    if lighting is None or lighting == "auto":
        return not textured
    if lighting == "on":
        return True
    if lighting == "off":
        return False
    raise InvalidParameterError(
        f"lighting must be True, False, 'on', 'off' or 'auto', got {lighting!r}."
    )


@dataclass(frozen=True, init=False)
class Style:
    """What a frame looks like (none of it changes the cut), validated when made.

    lighting: True/"on" modulates the colour by the light, False/"off" draws it unlit (decal),
    "auto" lights untextured terrain only (``resolve_lighting``). sun: the light of
    ``lighting`` and of the side walls (a Sun, or (azimuth, altitude) in degrees; None: the
    default Sun). background: a Background, or what ``Background.parse`` reads
    ("transparent", "sky", a colour name, "#rrggbb", (r, g, b)); an opaque one makes the
    read-back image opaque. wireframe: draw triangle edges instead of filled triangles.
    """

    lighting: bool | str | None
    sun: Sun
    background: Background
    wireframe: bool

    def __init__(
        self,
        lighting: bool | str | None = "auto",
        sun: Sun | tuple[float, float] | None = None,
        background: Background | str | tuple | None = None,
        wireframe: bool = False,
    ) -> None:
        resolve_lighting(lighting, textured=False)  # a bad mode fails here
        object.__setattr__(self, "lighting", lighting)
        object.__setattr__(self, "sun", as_sun(sun))
        object.__setattr__(self, "background", Background.parse(background))
        object.__setattr__(self, "wireframe", bool(wireframe))

    def lit(self, textured: bool) -> bool:
        """Whether the light modulates the colour of terrain that is ``textured`` or not."""
        return resolve_lighting(self.lighting, textured)
