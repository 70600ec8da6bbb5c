"""Thematic textures: a class raster or a continuous field turned into colours by a mapper.

Mappers (each a callable (rows, cols) values + valid mask → (rows, cols, 4) uint8):

- ``ClassTable``: class value → colour, from a dict or a raster's embedded colour table.
- ``ColourRamp``: a continuous field through a matplotlib colormap between vmin and vmax.
- ``ColourReliefFile``: a ``gdaldem color-relief`` colour file (``value R G B [A]``, ``nv``,
  percentages, GRASS colour names), interpolated exactly as gdaldem does.

Land-cover legends (``LEGENDS``): the standard NLCD colours and the GRASS landclass96 classes
(the NC sample's land use) in NLCD's colours. Maps soften legend colours (``soften``: less
saturated, lighter) so the shading they are blended with stays readable.

Vector layers (roads, rivers) become thematic layers by rasterization (``rasterize_lines``).

A mapper that has ``for_strips(values, valid)`` returns the mapper a strip of the lattice is
coloured with, its whole-lattice figures (a ramp's range, a colour file's percentages) resolved
once: a thematic texture is then coloured strip by strip (``ThematicTexture.band_strips``),
never whole as RGBA.
"""

from __future__ import annotations

import copy
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.io._common import check_shapefile_length, reading
from approxtree.io.gdal import no_side_files
from approxtree.textures.base import TextureData

Colour = tuple[int, int, int, int]

#: GRASS colour names understood in gdaldem colour files.
NAMED_COLOURS: dict[str, tuple[int, int, int]] = {
    "white": (255, 255, 255),
    "black": (0, 0, 0),
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "yellow": (255, 255, 0),
    "magenta": (255, 0, 255),
    "cyan": (0, 255, 255),
    "aqua": (0, 191, 191),
    "grey": (191, 191, 191),
    "gray": (191, 191, 191),
    "orange": (255, 127, 0),
    "brown": (191, 127, 63),
    "purple": (127, 0, 255),
    "violet": (127, 0, 255),
    "indigo": (0, 127, 255),
}


#: Land-cover legends: class value → (name, RGB). NLCD: the USGS National Land Cover Database
#: legend (mrlc.gov); landclass96: GRASS's North Carolina land classes in NLCD's colours.
LEGENDS: dict[str, dict[int, tuple[str, tuple[int, int, int]]]] = {
    "nlcd": {
        11: ("Open water", (70, 107, 159)),
        12: ("Perennial ice/snow", (209, 222, 248)),
        21: ("Developed, open space", (222, 197, 197)),
        22: ("Developed, low intensity", (217, 146, 130)),
        23: ("Developed, medium intensity", (235, 0, 0)),
        24: ("Developed, high intensity", (171, 0, 0)),
        31: ("Barren land", (179, 172, 159)),
        41: ("Deciduous forest", (104, 171, 95)),
        42: ("Evergreen forest", (28, 95, 44)),
        43: ("Mixed forest", (181, 197, 143)),
        52: ("Shrub/scrub", (204, 184, 121)),
        71: ("Grassland/herbaceous", (223, 223, 194)),
        81: ("Pasture/hay", (220, 217, 57)),
        82: ("Cultivated crops", (171, 108, 40)),
        90: ("Woody wetlands", (184, 217, 235)),
        95: ("Emergent herbaceous wetlands", (108, 159, 184)),
    },
    "landclass96": {
        1: ("Developed", (217, 146, 130)),
        2: ("Agriculture", (220, 217, 57)),
        3: ("Herbaceous", (223, 223, 194)),
        4: ("Shrubland", (204, 184, 121)),
        5: ("Forest", (104, 171, 95)),
        6: ("Water", (70, 107, 159)),
        7: ("Sediment", (179, 172, 159)),
    },
}
#: The water class of each legend (drawn over streams).
WATER_CLASSES: dict[str, tuple[int, ...]] = {"nlcd": (11,), "landclass96": (6,)}

#: What the palette of a thematic raster may be, in the words of the errors that list them.
THEMATIC_PALETTE_KINDS = (
    f"a land-cover legend ({', '.join(LEGENDS)}), a gdaldem colour file (lines 'value R G B') "
    "or a matplotlib colormap name such as 'terrain'"
)
#: How much ``soften`` moves a legend colour towards a light grey by default.
SOFTEN = 0.35


def soften(rgb: tuple[int, ...], amount: float = SOFTEN) -> tuple[int, int, int]:
    """A legend colour made quieter for blending with shading: its saturation reduced and its
    lightness raised by ``amount`` (0: unchanged, 1: the light grey (235, 235, 230))."""
    c = np.asarray(rgb[:3], dtype=np.float64)
    grey = c.mean()
    c = grey + (1.0 - 0.5 * amount) * (c - grey)
    c = c + amount * (np.array([235.0, 235.0, 230.0]) - c)
    r, g, b = (int(v) for v in np.clip(np.rint(c), 0, 255))
    return (r, g, b)


def _valid_range(values: np.ndarray, valid: np.ndarray) -> tuple[float, float] | None:
    """(min, max) of the valid values of (rows, cols) ``values``, or None when none is valid;
    computed without a copy of them."""
    if not valid.any():
        return None
    # The first valid value starts both reductions (an integer raster takes no infinity).
    first = values.flat[int(np.argmax(valid))]
    lo = float(np.min(values, where=valid, initial=first))
    hi = float(np.max(values, where=valid, initial=first))
    return lo, hi


class ClassTable:
    """Class value → RGBA colour; unknown classes and nodata are transparent."""

    def __init__(self, colours: Mapping[int, tuple[int, ...]]) -> None:
        self.colours: dict[int, Colour] = {}
        for k, c in colours.items():
            if len(c) not in (3, 4):
                raise InvalidParameterError(f"Colour of class {k} must be RGB or RGBA, got {c}.")
            r, g, b = (int(v) for v in c[:3])
            self.colours[int(k)] = (r, g, b, int(c[3]) if len(c) == 4 else 255)

    @classmethod
    def from_raster(cls, path: str | os.PathLike, band: int = 1) -> ClassTable:
        """The colour table embedded in a raster (e.g. a GeoTIFF palette)."""
        import rasterio

        with reading(path, "a thematic raster"):
            try:
                with no_side_files(), rasterio.open(path) as ds:
                    return cls(ds.colormap(band))
            except ValueError as exc:
                raise TerrainFormatError(f"{path} has no embedded colour table: {exc}") from exc

    @classmethod
    def legend(cls, name: str, amount: float = SOFTEN) -> ClassTable:
        """The softened colours of a legend of ``LEGENDS`` ("nlcd", "landclass96")."""
        if name not in LEGENDS:
            raise InvalidParameterError(
                f"Unknown legend {name!r}; choose one of {', '.join(LEGENDS)}."
            )
        return cls({k: soften(rgb, amount) for k, (_, rgb) in LEGENDS[name].items()})

    def softened(self, amount: float = SOFTEN) -> ClassTable:
        """This table with every colour softened (``soften``), alphas kept."""
        return ClassTable({k: (*soften(c, amount), c[3]) for k, c in self.colours.items()})

    def __call__(self, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
        keys = np.array(sorted(self.colours), dtype=np.int64)
        lut = np.array([self.colours[k] for k in keys], dtype=np.uint8).reshape(-1, 4)
        classes = np.where(valid, values, keys.min() - 1 if len(keys) else 0).astype(np.int64)
        pos = np.clip(np.searchsorted(keys, classes), 0, max(len(keys) - 1, 0))
        known = valid & (keys[pos] == classes) if len(keys) else np.zeros_like(valid)
        out = np.zeros((*values.shape, 4), dtype=np.uint8)
        out[known] = lut[pos[known]]
        return out

    def for_strips(self, values: np.ndarray, valid: np.ndarray) -> ClassTable:
        """The mapper of a strip: a class table needs no whole-lattice figure."""
        return self


class ColourRamp:
    """A continuous field through a matplotlib colormap, vmin → 0 and vmax → 1."""

    def __init__(
        self, cmap: str = "terrain", vmin: float | None = None, vmax: float | None = None
    ) -> None:
        import matplotlib

        try:
            self.cmap = matplotlib.colormaps[cmap]
        except KeyError as exc:
            raise InvalidParameterError(
                f"Unknown colormap {cmap!r}; a thematic raster takes {THEMATIC_PALETTE_KINDS}."
            ) from exc
        self.vmin, self.vmax = vmin, vmax

    def _range(self, values: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
        """(vmin, vmax): as given, else the valid values' own (0 and 1 when none is valid)."""
        found = _valid_range(values, valid) if self.vmin is None or self.vmax is None else None
        vmin = found[0] if self.vmin is None and found else (self.vmin or 0.0)
        vmax = found[1] if self.vmax is None and found else (self.vmax or 1.0)
        return vmin, vmax

    def for_strips(self, values: np.ndarray, valid: np.ndarray) -> ColourRamp:
        """The mapper of a strip: this ramp with the whole lattice's range fixed."""
        fixed = copy.copy(self)
        fixed.vmin, fixed.vmax = self._range(values, valid)
        return fixed

    def __call__(self, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
        vmin, vmax = self._range(values, valid)
        t = (values - vmin) / (vmax - vmin) if vmax > vmin else np.zeros_like(values)
        out = self.cmap(np.clip(np.nan_to_num(t), 0.0, 1.0), bytes=True)
        out[~valid] = 0
        return out


class ColourReliefFile:
    """A gdaldem colour-relief file, applied with gdaldem's linear interpolation.

    Lines are ``value R G B [A]`` (or a GRASS colour name), ``nv`` for nodata and ``N%`` for a
    percentage of the [min, max] range of the valid values; ``#`` starts a comment. Nodata
    takes the ``nv`` colour, or stays transparent: unlike gdaldem, which looks the nodata value
    up like an elevation when the file has no ``nv`` line, nodata is never coloured as a height.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise TerrainFormatError(f"Colour file {self.path} does not exist.")
        self.entries: list[tuple[str, Colour]] = []
        self.nodata_colour: Colour | None = None
        for lineno, raw in enumerate(self.path.read_text().splitlines(), 1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            tokens = [t for t in re.split(r"[\s,:]+", line) if t]
            value, colour = tokens[0], self._colour(tokens[1:], lineno)
            if value.lower() == "nv":
                self.nodata_colour = colour
            else:
                self.entries.append((value, colour))
        if not self.entries:
            raise TerrainFormatError(f"Colour file {self.path} holds no colour entry.")

    def _colour(self, tokens: list[str], lineno: int) -> Colour:
        if len(tokens) == 1 and tokens[0].lower() in NAMED_COLOURS:
            return (*NAMED_COLOURS[tokens[0].lower()], 255)
        try:
            vals = [int(float(t)) for t in tokens]
        except ValueError:
            vals = []
        if len(vals) not in (3, 4):
            raise TerrainFormatError(
                f"{self.path}:{lineno}: expected 'value R G B [A]' or a colour name, got "
                f"{' '.join(tokens)!r}."
            )
        return (vals[0], vals[1], vals[2], vals[3] if len(vals) == 4 else 255)

    def table(self, values: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sorted entry values (k,) and their colours (k, 4), percentages resolved."""
        lo, hi = _valid_range(values, valid) or (0.0, 0.0)
        keys = []
        for value, _ in self.entries:
            if value.endswith("%"):
                keys.append(lo + float(value[:-1]) / 100.0 * (hi - lo))
            else:
                keys.append(float(value))
        order = np.argsort(np.array(keys), kind="stable")
        k = np.array(keys)[order]
        c = np.array([self.entries[i][1] for i in order], dtype=np.float64)
        return k, c

    def for_strips(self, values: np.ndarray, valid: np.ndarray) -> _FixedRelief:
        """The mapper of a strip: this file's table with the whole lattice's percentages."""
        return _FixedRelief(self, *self.table(values, valid))

    def __call__(self, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
        return self.apply(values, valid, *self.table(values, valid))

    def apply(
        self, values: np.ndarray, valid: np.ndarray, keys: np.ndarray, colours: np.ndarray
    ) -> np.ndarray:
        """(rows, cols, 4) uint8: ``values`` coloured by the table (``keys`` (k,), ``colours``
        (k, 4)), nodata in the ``nv`` colour or transparent."""
        v = np.where(valid, values, keys[0]).astype(np.float64)
        # Index i of the first entry >= v: below the first or above the last entry the end
        # colours hold; between entries each channel is int(0.45 + a + t (b − a)), which is
        # what gdaldem 3.6 computes (measured pixel for pixel against it).
        i = np.searchsorted(keys, v, side="left")
        lo = np.clip(i - 1, 0, len(keys) - 1)
        hi = np.clip(i, 0, len(keys) - 1)
        span = keys[hi] - keys[lo]
        t = np.where(span > 0, (v - keys[lo]) / np.where(span > 0, span, 1.0), 0.0)
        exact = keys[hi] == v
        mixed = np.floor(0.45 + colours[lo] + t[..., None] * (colours[hi] - colours[lo]))
        mixed = np.where(exact[..., None], colours[hi], mixed)
        out = np.clip(mixed, 0, 255).astype(np.uint8)
        out[~valid] = self.nodata_colour if self.nodata_colour is not None else (0, 0, 0, 0)
        return out


class _FixedRelief:
    """A colour file's mapper with its table resolved: keys (k,) and colours (k, 4)."""

    def __init__(self, relief: ColourReliefFile, keys: np.ndarray, colours: np.ndarray) -> None:
        self.relief, self.keys, self.colours = relief, keys, colours

    def __call__(self, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
        return self.relief.apply(values, valid, self.keys, self.colours)


class ThematicTexture(TextureData):
    """Thematic data on a georeferenced lattice, coloured by a mapper.

    values: (rows, cols) numbers (class codes or a continuous field); valid: (rows, cols) bool
    or None (finite values); transform: affine pixel corner → world; mapper: ClassTable,
    ColourRamp, ColourReliefFile or any callable (values, valid) → (rows, cols, 4) uint8.
    """

    def __init__(
        self,
        values: np.ndarray,
        transform: Affine,
        mapper,
        crs: str | None = None,
        valid: np.ndarray | None = None,
    ) -> None:
        values = np.asarray(values)
        if values.ndim != 2:
            raise InvalidParameterError(f"Thematic values must be 2-D, got {values.shape}.")
        self.values = values
        self.valid = np.isfinite(values) if valid is None else np.asarray(valid, dtype=bool)
        self.transform = transform
        self.shape = (int(values.shape[0]), int(values.shape[1]))
        self.crs = crs
        self.mapper = mapper

    @classmethod
    def from_raster(cls, path: str | os.PathLike, mapper=None, band: int = 1) -> ThematicTexture:
        """Read a thematic raster; without a mapper its embedded colour table is used."""
        import rasterio

        path = Path(path)
        if not path.is_file():
            raise TerrainFormatError(f"Thematic raster {path} does not exist.")
        # A file GDAL cannot open or decode is one TerrainFormatError, as a DEM's would be.
        with reading(path, "a thematic raster"), no_side_files(), rasterio.open(path) as ds:
            data = ds.read(band, masked=True)
            transform, crs = ds.transform, ds.crs.to_string() if ds.crs else None
            if mapper is None:
                try:
                    mapper = ClassTable(ds.colormap(band))
                except ValueError as exc:
                    raise InvalidParameterError(
                        f"{path} has no embedded colour table; give a mapper (a colour "
                        "ramp or a colour file)."
                    ) from exc
        valid = ~np.ma.getmaskarray(data)
        return cls(np.ma.getdata(data), transform, mapper, crs=crs, valid=valid)

    def rgba(self) -> np.ndarray:
        return self.mapper(self.values, self.valid)

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        """Coloured strip by strip when the mapper can (``for_strips``): RGBA and the mapper's
        temporaries are never whole-lattice; other mappers colour the whole lattice once."""
        for_strips = getattr(self.mapper, "for_strips", None)
        if for_strips is None:
            yield from super().band_strips(rows)
            return
        mapper = for_strips(self.values, self.valid)
        for r0 in range(0, self.shape[0], rows):
            rgba = mapper(self.values[r0 : r0 + rows], self.valid[r0 : r0 + rows])
            yield np.ascontiguousarray(np.moveaxis(rgba, -1, 0))


def rasterize_lines(
    path: str | os.PathLike,
    transform: Affine,
    shape: tuple[int, int],
    crs: str | None,
    colour: tuple[int, ...] = (30, 90, 200, 255),
    width: float | None = None,
) -> ThematicTexture:
    """A vector layer (lines or polygons, read with pyogrio) as a thematic texture.

    The geometries are reprojected to ``crs`` when the layer's CRS differs, buffered to
    ``width`` world units (default: one texel; 0: not buffered) and burnt into a (rows, cols)
    lattice in ``colour`` (RGBA 0..255).
    """
    import pyogrio
    import shapely
    from rasterio.features import rasterize
    from rasterio.warp import transform_geom

    path = Path(path)
    if not path.is_file():
        raise TerrainFormatError(f"Vector layer {path} does not exist.")
    check_shapefile_length(path)
    try:
        info = pyogrio.read_info(path)
        _, _, wkb, _ = pyogrio.raw.read(path, read_geometry=True, columns=[])
    except Exception as exc:
        raise TerrainFormatError(f"Cannot read {path} as a vector layer: {exc}") from exc
    if wkb is None:
        raise TerrainFormatError(f"{path} has no geometry column: it holds no shapes.")
    found = shapely.from_wkb(wkb)
    geoms: Iterable[Any] = found[~shapely.is_missing(found)]
    src_crs = info.get("crs")
    # Reproject only when both CRSs are known and differ.
    if crs and src_crs:
        from rasterio.crs import CRS

        if CRS.from_user_input(src_crs) != CRS.from_user_input(crs):
            geoms = [
                shapely.geometry.shape(transform_geom(src_crs, crs, g.__geo_interface__))
                for g in geoms
            ]
    w = width if width is not None else max(abs(transform.a), abs(transform.e))
    if w > 0:
        # Buffered one part at a time, and only near the lattice: buffering a whole
        # multi-part layer unions every part's outline (4 s a layer on Luxembourg's roads).
        # Every point of the lattice within w/2 of a line is within w/2 of a part of it
        # inside the lattice's bounds grown by w, so the burnt texels are the same.
        rows, cols = shape
        xs = (transform.c, transform.c + cols * transform.a)
        ys = (transform.f, transform.f + rows * transform.e)
        parts = shapely.get_parts(np.asarray(list(geoms), dtype=object))
        near = shapely.clip_by_rect(parts, min(xs) - w, min(ys) - w, max(xs) + w, max(ys) + w)
        near = near[~shapely.is_empty(near)]
        shapes = [(g, 1) for g in shapely.buffer(near, w / 2.0)]
    else:
        # Width 0 burns polygons as they are (water bodies) and lines one texel wide.
        shapes = [(g, 1) for g in geoms]
    burnt = (
        rasterize(
            shapes, out_shape=shape, transform=transform, fill=0, dtype="uint8", all_touched=False
        )
        if shapes
        else np.zeros(shape, dtype=np.uint8)
    )
    return ThematicTexture(burnt, transform, ClassTable({1: colour}), crs=crs, valid=burnt > 0)
