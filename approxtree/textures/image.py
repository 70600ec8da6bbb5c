"""ImageTexture: an RGB(A), grey or paletted raster in any CRS, reprojected onto a lattice.

The image (anything GDAL reads: GeoTIFF/COG, JPEG or PNG with a world file, a VRT mosaic) is
warped by GDAL onto the texture lattice one strip of the lattice at a time
(``rasterio.warp.reproject`` of the strip's window, ``band_strips``): GDAL reads only the
source blocks under that strip, so an image larger than memory bakes with the memory of a
strip (and ``CACHE_MB`` of GDAL's block cache). The warp's resampling scale is fixed once
for the whole lattice (``io.warp.warp_scale``), so the texels do not depend on where the
strips are cut, and equal gdalwarp's within 1 level.

Transparency: an alpha band is warped as alpha; otherwise a declared nodata value or a
per-dataset mask (an internal or ``.msk`` mask) marks the texels GDAL leaves out, and the
warper's added alpha band makes them, and the lattice outside the image, transparent.
Paletted images are sampled nearest (colour indices do not interpolate), then looked up in
their colour table (its alpha kept).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry.rect import Rect
from approxtree.io._common import reading
from approxtree.io.gdal import no_side_files
from approxtree.io.warp import RESAMPLINGS, warp_scale
from approxtree.textures.base import TextureData

#: GDAL's block cache while an image is warped (MB): a strip's source blocks are read once,
#: so a larger cache only grows with the image (GDAL's default is 5 % of the RAM).
CACHE_MB = 128


def _resampling(name: str):
    """rasterio's Resampling member for a name of ``io.warp.RESAMPLINGS``."""
    from rasterio.enums import Resampling

    if name not in RESAMPLINGS:
        raise InvalidParameterError(
            f"Unknown resampling {name!r}; choose one of {', '.join(RESAMPLINGS)}."
        )
    return Resampling[RESAMPLINGS[name]]


class _Layout:
    """What an image's bands are: (kind, colour band indexes, alpha band index or None, LUT).

    kind: "rgb" (3 colour bands), "grey" (1) or "palette" (1 band of indices, ``lut``
    (256, 4) uint8). Raises TerrainFormatError for any other band layout or dtype.
    """

    def __init__(self, ds, path: Path) -> None:
        from rasterio.enums import ColorInterp

        interp = list(ds.colorinterp)
        alpha = [i + 1 for i, c in enumerate(interp) if c == ColorInterp.alpha]
        if set(ds.dtypes) != {"uint8"}:
            raise TerrainFormatError(
                f"{path} has {'/'.join(sorted(set(ds.dtypes)))} bands; an image texture must "
                "be 8-bit (scale it first, e.g. gdal_translate -ot Byte -scale)."
            )
        self.alpha: int | None = alpha[-1] if alpha else None
        colour = [i for i in range(1, ds.count + 1) if i != self.alpha]
        self.lut: np.ndarray | None = None
        if len(colour) == 3:
            self.kind = "rgb"
        elif len(colour) == 1 and interp[colour[0] - 1] == ColorInterp.palette:
            self.kind = "palette"
            self.lut = np.zeros((256, 4), dtype=np.uint8)
            for k, c in ds.colormap(colour[0]).items():
                self.lut[k] = c
        elif len(colour) == 1:
            self.kind = "grey"
        else:
            raise TerrainFormatError(
                f"{path} has {ds.count} bands ({', '.join(c.name for c in interp)}); an image "
                "texture is RGB, RGBA, grey, grey + alpha or paletted (give the colour bands "
                "with gdal_translate -b, or mark the alpha band with -colorinterp)."
            )
        self.colour = colour


class ImageTexture(TextureData):
    """An image reprojected onto a lattice: (rows, cols, 4) uint8 RGBA, alpha 0 outside it.

    path: the image; transform, shape (rows, cols), crs: the lattice (the terrain's CRS);
    resampling: a name of ``io.warp.RESAMPLINGS`` (paletted images are always sampled nearest).
    An image without a CRS is refused over a terrain that has one (and taken to share the
    terrain's coordinates over one without); an image that does not overlap the lattice is
    refused.
    """

    bands = 4

    def __init__(
        self,
        path: str | os.PathLike,
        transform: Affine,
        shape: tuple[int, int],
        crs: str | None,
        resampling: str = "bilinear",
    ) -> None:
        import rasterio

        self.path = Path(path)
        self.transform = transform
        self.shape = (int(shape[0]), int(shape[1]))
        self.crs = crs
        self.resampling = resampling
        self._method = _resampling(resampling)
        if not self.path.is_file():
            raise TerrainFormatError(f"Image {self.path} does not exist.")
        with reading(self.path, "an image"), no_side_files(), rasterio.open(self.path) as ds:
            self._layout = _Layout(ds, self.path)
            self.source_crs = _source_crs(ds, self.path, crs)
            bounds = ds.bounds
        self.footprint = _footprint(bounds, self.source_crs, crs, self.path)
        common = self.footprint.intersection(self.extent)
        if common is None or common.area == 0:
            raise InvalidParameterError(
                f"Image {self.path} does not overlap the terrain: it covers "
                f"{_shown(self.footprint)} in the terrain's CRS, the terrain "
                f"{_shown(self.extent)}; check both CRSs."
            )

    def rgba(self) -> np.ndarray:
        out = np.empty((*self.shape, 4), dtype=np.uint8)
        r0 = 0
        for strip in self.band_strips(512):
            n = strip.shape[1]
            out[r0 : r0 + n] = np.moveaxis(strip, 0, -1)
            r0 += n
        return out

    def band_strips(
        self, rows: int, start: int = 0, stop: int | None = None
    ) -> Iterator[np.ndarray]:
        """(4, ≤ rows, cols) uint8 RGBA strips from the top, each warped by GDAL when asked
        for (``rasterio.warp.reproject`` of the strip's window: only the source blocks under
        it are read, in chunks of GDAL's warp memory). start, stop: only the lattice rows
        start..stop, the same texels (the scale is the whole lattice's; a re-bake warps the
        rows it re-blends)."""
        import rasterio
        from rasterio.enums import Resampling
        from rasterio.warp import reproject

        n_rows, cols = self.shape
        layout = self._layout
        method = Resampling.nearest if layout.kind == "palette" else self._method
        bands = len(layout.colour) + 1
        with (
            reading(self.path, "an image"),
            no_side_files(),
            rasterio.Env(GDAL_CACHEMAX=CACHE_MB),
            rasterio.open(self.path) as ds,
        ):
            options = {
                "src_crs": self.source_crs,
                "dst_crs": self.crs or self.source_crs,
                "resampling": method,
                "dst_alpha": bands,
                "init_dest_nodata": False,
                **warp_scale(ds, self.source_crs, self.crs, self.transform, self.shape),
            }
            if layout.alpha is not None:
                source = rasterio.band(ds, [*layout.colour, layout.alpha])
                options["src_alpha"] = bands
            else:
                # No alpha band: the nodata value or the mask marks what GDAL leaves out,
                # and the warper's alpha band makes it (and the lattice past the image) 0.
                source = rasterio.band(ds, layout.colour)
            end = n_rows if stop is None else min(stop, n_rows)
            for r0 in range(start, end, rows):
                n = min(rows, end - r0)
                planes = np.zeros((bands, n, cols), dtype=np.uint8)
                reproject(
                    source,
                    planes,
                    dst_transform=self.transform @ Affine.translation(0, r0),
                    **options,
                )
                yield _to_rgba(planes, layout)


def _to_rgba(planes: np.ndarray, layout: _Layout) -> np.ndarray:
    """(colour bands + alpha, n, cols) warped planes → (4, n, cols) uint8 RGBA."""
    n, cols = planes.shape[1:]
    out = np.empty((4, n, cols), dtype=np.uint8)
    alpha = planes[-1]
    if layout.kind == "rgb":
        out[:3] = planes[:3]
        out[3] = alpha
    elif layout.kind == "grey":
        out[:3] = planes[0]
        out[3] = alpha
    else:
        lut = layout.lut if layout.lut is not None else np.zeros((256, 4), np.uint8)
        colours = lut[planes[0]]
        out[:] = np.moveaxis(colours, -1, 0)
        np.minimum(out[3], alpha, out=out[3])
    # Transparent texels carry no colour (the pyramid's halving weighs colour by alpha).
    out[:3, alpha == 0] = 0
    return out


def _shown(rect: Rect) -> str:
    """A rectangle as "x0..x1 × y0..y1" with 6 significant digits."""
    return f"x {rect.xmin:.6g}..{rect.xmax:.6g}, y {rect.ymin:.6g}..{rect.ymax:.6g}"


def _source_crs(ds, path: Path, crs: str | None):
    """The image's CRS; without one, the terrain's when the terrain has none either."""
    from rasterio.crs import CRS

    if ds.crs is not None:
        return ds.crs
    if crs is not None:
        raise TerrainFormatError(
            f"Image {path} has no CRS, and the terrain is in {crs}; give it one "
            "(gdal_edit.py -a_srs, or a .prj / .aux.xml beside it)."
        )
    if ds.transform == Affine.identity():
        raise TerrainFormatError(
            f"Image {path} has no georeference (no CRS, no geotransform or world file)."
        )
    # Neither has a CRS: the image is taken in the terrain's coordinates; any projected CRS
    # stands in for both (the warp is then an affine resampling).
    return CRS.from_epsg(3857)


def _footprint(bounds, source_crs, crs: str | None, path: Path) -> Rect:
    """The image's bounds in the terrain's CRS (densified edges)."""
    from rasterio.warp import transform_bounds

    if crs is None:
        return Rect(bounds.left, bounds.bottom, bounds.right, bounds.top)
    with reading(path, "an image"):
        x0, y0, x1, y1 = transform_bounds(source_crs, crs, *bounds, densify_pts=21)
    if not all(np.isfinite([x0, y0, x1, y1])):
        raise InvalidParameterError(
            f"Image {path} cannot be projected into the terrain's CRS {crs} (it lies outside "
            "that CRS's area of use)."
        )
    return Rect(x0, y0, x1, y1)


def image_resolution(path: str | os.PathLike, crs: str | None) -> float:
    """The image's finest cell size in the terrain's CRS units (GDAL's suggested warp
    resolution), to choose a default texel size."""
    import rasterio
    from rasterio.warp import calculate_default_transform

    with reading(path, "an image"), no_side_files(), rasterio.open(path) as ds:
        if ds.crs is None or crs is None:
            return float(min(ds.res))
        t, _, _ = calculate_default_transform(ds.crs, crs, ds.width, ds.height, *ds.bounds)
        return float(min(abs(t.a), abs(t.e)))
