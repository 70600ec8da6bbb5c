"""Hypsometric palettes for relief maps: a cartographer's tint laid over the terrain's own
elevation range by default, or colours tied to elevations in metres on request.

Each palette is a list of (elevation, (r, g, b)) stops (cpt-city style), linear in between and
held constant outside. ``relative`` palettes run their stops over [0, 1] of the terrain's own z
range (min..max), so 100 m of relief (North Carolina's piedmont) spans the whole tint, and data
whose z is not an elevation in metres (feet, file units) is coloured as well; the fixed ones tie
each colour to an elevation in metres, so a 150 m hill stays lowland green and snow white only
appears on high mountains.

Named choices (``PALETTES``):

- ``hypsometric`` (default, relative): the atlas tints — green lowlands, yellow and ochre
  hills, brown heights — stretched over the terrain's min..max.
- ``relief`` (fixed): the Wikipedia/cpt-city "wiki-2.0" hypsometric tints — greens in the
  lowlands, pale yellow and tan hills, browns in the mountains, greys then white above 4500 m.
- ``atlas`` (fixed): a more saturated school-atlas ramp (green, yellow, ochre, brown, white).
- ``grey``: one light grey (the shading alone carries the relief).
- ``stretched`` (relative): the former ramp over the data's min..max (green → white).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.textures.thematic import LEGENDS, THEMATIC_PALETTE_KINDS


@dataclass(frozen=True)
class Palette:
    """A hypsometric palette. stops: ((elevation, (r, g, b) 0..255), ...) ascending;
    relative: stops run over [0, 1] of the terrain's z range instead of metres."""

    name: str
    stops: tuple[tuple[float, tuple[int, int, int]], ...]
    relative: bool = False

    def colours(self, z: np.ndarray, z_range: tuple[float, float] | None = None) -> np.ndarray:
        """(..., 3) float colours in [0, 1] at heights z (...); z_range: the terrain's
        (min, max) for relative palettes."""
        keys, rgb = self._table()
        z = np.asarray(z, dtype=np.float64)
        if self.relative:
            lo, hi = z_range if z_range is not None else (float(np.nanmin(z)), np.nanmax(z))
            z = (z - lo) / max(float(hi) - float(lo), 1e-12)
        return np.stack([np.interp(z, keys, rgb[:, c]) for c in range(3)], axis=-1)

    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        keys = np.array([k for k, _ in self.stops], dtype=np.float64)
        rgb = np.array([c for _, c in self.stops], dtype=np.float64) / 255.0
        return keys, rgb

    def lookup_table(
        self, z_range: tuple[float, float], texels: int = 1024
    ) -> tuple[np.ndarray, tuple[float, float]]:
        """The palette sampled for a shader: ((texels, 3) uint8, (z at texel 0's centre, z at
        the last texel's centre)). Absolute palettes cover their stops, but at least the
        terrain's z range (constant colours beyond the stops); relative ones the z range."""
        z0, z1 = (float(v) for v in z_range)
        if not self.relative:
            keys, _ = self._table()
            z0, z1 = min(z0, keys[0]), max(z1, keys[-1])
        if z1 <= z0:
            z1 = z0 + 1.0
        zs = np.linspace(z0, z1, texels)
        rgb = self.colours(zs, (float(z_range[0]), float(z_range[1])))
        return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8), (z0, z1)


PALETTES: dict[str, Palette] = {
    "hypsometric": Palette(
        "hypsometric",
        (
            (0.0, (86, 150, 92)),
            (0.2, (128, 178, 102)),
            (0.4, (196, 210, 128)),
            (0.6, (232, 220, 150)),
            (0.8, (214, 180, 118)),
            (0.9, (190, 142, 92)),
            (1.0, (160, 112, 76)),
        ),
        relative=True,
    ),
    "relief": Palette(
        "relief",
        (
            (-500.0, (161, 196, 221)),
            (0.0, (172, 208, 165)),
            (50.0, (148, 191, 139)),
            (100.0, (168, 198, 143)),
            (200.0, (189, 204, 150)),
            (400.0, (209, 215, 171)),
            (600.0, (225, 228, 181)),
            (800.0, (239, 235, 192)),
            (1000.0, (232, 225, 182)),
            (1250.0, (222, 214, 163)),
            (1500.0, (211, 202, 157)),
            (1750.0, (202, 185, 130)),
            (2000.0, (195, 167, 107)),
            (2500.0, (185, 152, 90)),
            (3000.0, (170, 135, 83)),
            (3500.0, (172, 154, 124)),
            (4000.0, (186, 174, 154)),
            (4500.0, (202, 195, 184)),
            (5000.0, (224, 222, 216)),
            (6000.0, (245, 244, 242)),
        ),
    ),
    "atlas": Palette(
        "atlas",
        (
            (0.0, (86, 150, 92)),
            (100.0, (128, 178, 102)),
            (300.0, (196, 210, 128)),
            (600.0, (232, 220, 150)),
            (1000.0, (214, 180, 118)),
            (1500.0, (190, 142, 92)),
            (2000.0, (160, 112, 76)),
            (3000.0, (140, 112, 100)),
            (4000.0, (200, 196, 190)),
            (5000.0, (255, 255, 255)),
        ),
    ),
    "grey": Palette("grey", ((0.0, (214, 214, 210)), (1.0, (214, 214, 210)))),
    "stretched": Palette(
        "stretched",
        (
            (0.0, (51, 115, 64)),
            (0.25, (140, 166, 89)),
            (0.5, (204, 184, 115)),
            (0.8, (153, 115, 82)),
            (1.0, (242, 242, 242)),
        ),
        relative=True,
    ),
}
#: The palette of untextured terrain unless another is asked for: the terrain's own range.
DEFAULT_PALETTE = "hypsometric"


def get_palette(palette: str | Palette | None) -> Palette:
    """A Palette by name (PALETTES), a Palette, or None for the default."""
    if palette is None:
        return PALETTES[DEFAULT_PALETTE]
    if isinstance(palette, Palette):
        return palette
    try:
        return PALETTES[str(palette)]
    except KeyError:
        raise InvalidParameterError(
            f"Unknown palette {palette!r}; the elevation colours take a hypsometric palette: "
            f"{', '.join(PALETTES)}. A thematic raster takes {THEMATIC_PALETTE_KINDS} "
            "(approxtree bake --thematic RASTER --palette NAME)."
        ) from None


def check_thematic_palette(palette: str | None) -> None:
    """InvalidParameterError, naming every kind of palette, unless ``palette`` names what a
    thematic raster is coloured with: None, a legend, an existing file or a matplotlib
    colormap (a hypsometric palette of PALETTES colours elevations, not classes)."""
    if palette is None or palette in LEGENDS or Path(palette).is_file():
        return
    # Only a colormap name needs matplotlib (~0.1 s to import): a plain bake never loads it.
    import matplotlib

    if palette in matplotlib.colormaps:
        return
    what = (
        "is a hypsometric palette (elevation colours: approxtree render --palette)"
        if palette in PALETTES
        else "is neither a legend, a file nor a colormap"
    )
    raise InvalidParameterError(
        f"Unknown palette {palette!r} for the thematic raster: it {what}. A thematic raster "
        f"takes {THEMATIC_PALETTE_KINDS}; the hypsometric palettes {', '.join(PALETTES)} colour "
        "the elevations of an untextured terrain (render, view, demo --palette)."
    )
