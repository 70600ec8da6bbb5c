"""Imagery tiles from a baked texture pyramid (shading, thematic, overlays: ``approxtree bake``).

``ImageryTiles(pyramid, scheme)`` makes tile (z, x, y) of the geographic tiling (CesiumJS's
UrlTemplateImageryProvider over quantized-mesh terrain) or of Web Mercator (MapLibre,
Leaflet) as PNG, WEBP or JPEG:

1. the centres of the tile's pixels (``schemes.TileScheme.pixel_centres``; only those near the
   texture's footprint, the rest stay transparent) are carried into the pyramid's CRS by
   pyproj;
2. the pyramid level is the coarsest whose texels are no larger on the ground than the tile's
   pixels (at the tile's centre), level 0 when none is;
3. the pixels sample that level bilinearly, alpha premultiplied (texels beyond the texture are
   transparent, so its edge fades over half a texel); where the level's texels are still more
   than twice finer than a pixel (the coarsest zooms), its window is first halved k times
   as the pyramid halves its levels (``_box_reduce``);
4. given a ``DetailTextures`` (``--textures BASE --textures DETAIL@ZOOM``), the tiles of zoom
   ZOOM and deeper lay the detail pyramid's pixels (made by steps 1-3) over the base's, alpha
   over alpha: the detail shows inside its footprint and the base around it; map tiles have
   no tree, so the detail's level counts zooms here;
5. PNG and WEBP keep the alpha; JPEG has none and gets the texture over black.

The tile depends on (z, x, y) and the pyramid alone, so a written folder and the server agree
byte for byte. The default deepest zoom is the first whose pixels are no larger than level 0's
texels at the footprint's centre.
"""

from __future__ import annotations

import math
import threading
from functools import cached_property
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.kernels.rgba import halve_bands
from approxtree.textures.detail import DetailTextures, open_drape
from approxtree.tiles.map_tiles import EXTENSIONS, check_zooms, encode_image
from approxtree.tiles.schemes import TileScheme, ground_metres

#: Tile side (pixels) by default: CesiumJS's and Leaflet's.
DEFAULT_TILE_SIZE = 256


def texture_footprint(pyramid: Any):
    """Level 0's extent as a shapely polygon in lon/lat degrees (edges densified)."""
    from pyproj import Transformer
    from shapely import Polygon

    lv = pyramid.levels[0]
    t = lv.transform
    x0, y0 = t @ (0, 0)
    x1, y1 = t @ (lv.width, lv.height)
    s = np.linspace(0.0, 1.0, 65)
    xs = np.concatenate([x0 + (x1 - x0) * s, np.full(65, x1), x1 - (x1 - x0) * s, np.full(65, x0)])
    ys = np.concatenate([np.full(65, y0), y0 + (y1 - y0) * s, np.full(65, y1), y1 - (y1 - y0) * s])
    lon, lat = Transformer.from_crs(pyramid.crs, "EPSG:4326", always_xy=True).transform(xs, ys)
    if not (np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))):
        raise InvalidParameterError(
            f"The texture pyramid's extent does not map to longitude/latitude through its CRS "
            f"{pyramid.crs!r}; rebake it from a terrain with a valid CRS."
        )
    return Polygon(np.column_stack([lon, lat]))


class ImageryTiles:
    """Imagery tiles of one texture pyramid (a ``map_tiles.MapTiles`` source).

    pyramid: a TexturePyramid with a CRS, or a DetailTextures (module docstring, 4.);
    scheme: a ``schemes.TileScheme``; tile_size: pixels of a tile side; image_format: png,
    webp or jpeg; minzoom, maxzoom (None: the zoom of level 0's texels, the finer pyramid's).
    """

    def __init__(
        self,
        pyramid: Any,
        scheme: TileScheme,
        tile_size: int = DEFAULT_TILE_SIZE,
        image_format: str = "png",
        minzoom: int = 0,
        maxzoom: int | None = None,
    ) -> None:
        detail = pyramid if isinstance(pyramid, DetailTextures) else None
        if detail is not None:
            pyramid = detail.base
        if not pyramid.crs:
            raise InvalidParameterError(
                f"The texture pyramid {pyramid.folder} has no CRS, so it cannot be placed on "
                "the globe; bake it from a terrain with a CRS."
            )
        if image_format not in EXTENSIONS:
            raise InvalidParameterError(
                f"Unknown image format {image_format!r}; use png, webp or jpeg."
            )
        if tile_size not in (256, 512):
            raise InvalidParameterError(f"tile_size must be 256 or 512, got {tile_size!r}.")
        self.pyramid = pyramid
        self.scheme = scheme
        self.tile_size = tile_size
        self.image_format = image_format
        lv = pyramid.levels[0]
        cx, cy = lv.transform @ (lv.width / 2, lv.height / 2)
        a, e = lv.transform.a, lv.transform.e
        #: Ground size (m) of a level-0 texel and the latitude where it was measured.
        self.texel_metres, self.latitude = ground_metres(pyramid.crs, cx, cy, a, e)
        self.minzoom = minzoom
        self.maxzoom = (
            maxzoom
            if maxzoom is not None
            else max(scheme.zoom_for(self.texel_metres, tile_size, self.latitude), minzoom)
        )
        #: The detail pyramid's tiles and the zoom from which they cover the base's, or None.
        self.detail: ImageryTiles | None = None
        self.detail_zoom = 0
        if detail is not None:
            given = (scheme, tile_size, image_format, minzoom, maxzoom)
            self.detail, self.detail_zoom = ImageryTiles(detail.detail, *given), detail.level
            # By default the zooms go on to the finer pyramid's texels.
            self.maxzoom = max(self.maxzoom, self.detail.maxzoom)
        check_zooms(self.minzoom, self.maxzoom)
        self._local = threading.local()

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_local")
        state.pop("footprint", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._local = threading.local()

    @cached_property
    def footprint(self):
        if self.detail is None:
            return texture_footprint(self.pyramid)
        return texture_footprint(self.pyramid).union(self.detail.footprint)

    def describe(self) -> dict[str, Any]:
        if self.detail is None:
            return {"kind": "imagery", "levels": len(self.pyramid)}
        return {"kind": "imagery", "levels": len(self.pyramid), "detail_zoom": self.detail_zoom}

    def _to_crs(self):
        """This thread's pyproj transformer lon/lat → the pyramid's CRS."""
        t = getattr(self._local, "transformer", None)
        if t is None:
            from pyproj import Transformer

            t = Transformer.from_crs("EPSG:4326", self.pyramid.crs, always_xy=True)
            self._local.transformer = t
        return t

    def level_for(self, z: int, x: int, y: int) -> tuple[int, int]:
        """(level, factor): the pyramid level tile (z, x, y) samples — the coarsest whose
        texels are no larger on the ground than its pixels (at the tile's centre), 0 when none
        is — and the blocks (factor × factor texels, a power of two) averaged first where
        that level's texels are still more than twice finer than the pixels."""
        _, south, _, north = self.scheme.bounds(z, x, y)
        pixel = self.scheme.pixel_metres(z, self.tile_size, (south + north) / 2)
        ratio = pixel / self.texel_metres
        k = min(max(math.floor(math.log2(ratio)), 0), len(self.pyramid) - 1) if ratio >= 1 else 0
        rest = ratio / 2**k
        return int(k), 2 ** math.floor(math.log2(rest)) if rest >= 2 else 1

    def pixels(self, z: int, x: int, y: int) -> np.ndarray:
        """(size, size, 4) uint8 straight-alpha RGBA of tile (z, x, y) (module docstring)."""
        out = self._own_pixels(z, x, y)
        if self.detail is None or z < self.detail_zoom:
            return out
        return over(self.detail.pixels(z, x, y), out)

    def _own_pixels(self, z: int, x: int, y: int) -> np.ndarray:
        """(size, size, 4) uint8 straight-alpha RGBA of tile (z, x, y) of this pyramid alone
        (module docstring, 1.-3.)."""
        size = self.tile_size
        out = np.zeros((size, size, 4), dtype=np.uint8)
        if not self.scheme.exists(z, x, y):
            raise InvalidParameterError(
                f"Tile {z}/{x}/{y} is outside the {self.scheme.name} tiling."
            )
        # Texels more than twice finer than the pixels (the pyramid ends before the zoom's
        # pixel size) are averaged by blocks first, so a pixel is not one texel of many.
        k, factor = self.level_for(z, x, y)
        # The texture's edge fades over half a (block of) texel(s) beyond the footprint: the
        # pixels that far out are sampled too (2 more for the texel size's change over the
        # tile: it is measured at the pyramid's centre).
        _, south, _, north = self.scheme.bounds(z, x, y)
        pixel = self.scheme.pixel_metres(z, size, (south + north) / 2)
        margin = 2 + math.ceil(self.texel_metres * 2**k * factor / pixel / 2)
        rows, cols = self.scheme.pixel_span(z, x, y, size, self.footprint.bounds, margin)
        if rows.start >= rows.stop or cols.start >= cols.stop:
            return out
        lon, lat = self.scheme.pixel_centres(z, x, y, size, rows, cols)
        px, py = self._to_crs().transform(lon, lat)
        out[rows, cols] = self._sample(k, np.asarray(px), np.asarray(py), factor)
        return out

    def _sample(self, k: int, px: np.ndarray, py: np.ndarray, factor: int) -> np.ndarray:
        """(r, c, 4) uint8 RGBA: level k sampled bilinearly (premultiplied alpha) at the CRS
        points (r, c), its texels first averaged over factor × factor blocks."""
        lv = self.pyramid.levels[k]
        t = lv.transform
        fc = (px - t.c) / t.a - 0.5
        fr = (py - t.f) / t.e - 0.5
        finite = np.isfinite(fc) & np.isfinite(fr)
        result = np.zeros((*px.shape, 4), dtype=np.uint8)
        if not finite.any():
            return result
        # Coordinates on the grid of blocks (texels when factor is 1), block centres at
        # integers: a point mixes the blocks floor(u) and floor(u) + 1.
        u = (fc + 0.5) / factor - 0.5
        v = (fr + 0.5) / factor - 0.5
        # The blocks the points mix, within the level (beyond: transparent), at least its edge
        # block: points past the edge still fade from it. (Bounds taken on texels instead cut
        # a block off the window's low side, and points past the edge got nothing:
        # ``approxtree verify`` found both.)
        blocks_w, blocks_h = -(-lv.width // factor), -(-lv.height // factor)
        b0 = min(max(math.floor(u[finite].min()), 0), blocks_w - 1)
        a0 = min(max(math.floor(v[finite].min()), 0), blocks_h - 1)
        b1 = max(min(math.floor(u[finite].max()) + 2, blocks_w), b0 + 1)
        a1 = max(min(math.floor(v[finite].max()) + 2, blocks_h), a0 + 1)
        # Whole blocks of the reduction, aligned on the level's texel grid (texels past the
        # level's edge read as transparent).
        window = self.pyramid.read(
            k, a0 * factor, b0 * factor, (a1 - a0) * factor, (b1 - b0) * factor
        )
        if factor > 1:
            window = _box_reduce(window, factor)
        # One transparent block around the window: points past it fade to nothing.
        window = np.pad(window, ((1, 1), (1, 1), (0, 0)))
        h, w = window.shape[:2]
        u = u - b0 + 1.0
        v = v - a0 + 1.0
        u = np.where(finite, np.clip(u, 0.0, w - 1.0), 0.0)
        v = np.where(finite, np.clip(v, 0.0, h - 1.0), 0.0)
        iu = np.minimum(u.astype(np.int64), w - 2)
        iv = np.minimum(v.astype(np.int64), h - 2)
        du = (u - iu)[..., None].astype(np.float32)
        dv = (v - iv)[..., None].astype(np.float32)
        # The four texels around each point, alpha premultiplied, mixed bilinearly.
        mixed = np.zeros((*u.shape, 4), dtype=np.float32)
        for dr, dc, weight in (
            (0, 0, (1 - dv) * (1 - du)),
            (0, 1, (1 - dv) * du),
            (1, 0, dv * (1 - du)),
            (1, 1, dv * du),
        ):
            texel = window[iv + dr, iu + dc].astype(np.float32)
            texel[..., :3] *= texel[..., 3:] * (1.0 / 255.0)
            mixed += texel * weight
        mixed[~finite] = 0.0
        alpha = mixed[..., 3:]
        rgb = np.where(alpha > 0, mixed[..., :3] * 255.0 / np.maximum(alpha, 1e-6), 0.0)
        result[..., :3] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        result[..., 3] = np.clip(np.rint(alpha[..., 0]), 0, 255).astype(np.uint8)
        return result

    def tile(self, z: int, x: int, y: int) -> bytes:
        """Tile (z, x, y) encoded as the source's image format."""
        rgba = self.pixels(z, x, y)
        if self.image_format == "jpeg":
            # No alpha in JPEG: the texture over black.
            a = rgba[..., 3:].astype(np.float32) / 255.0
            rgb = np.rint(rgba[..., :3].astype(np.float32) * a).astype(np.uint8)
            return encode_image(rgb, "jpeg")
        return encode_image(rgba, self.image_format)


def _box_reduce(rgba: np.ndarray, factor: int) -> np.ndarray:
    """(h, w, 4) uint8 straight alpha (h, w multiples of ``factor``, a power of two) →
    (h / factor, w / factor, 4): each texel the alpha-weighted mean of a factor × factor block,
    as the pyramid halves its levels (``kernels.rgba.halve_bands``, applied log2(factor)
    times)."""
    bands = np.ascontiguousarray(np.moveaxis(rgba, -1, 0))
    while factor > 1:
        half = np.empty((4, -(-bands.shape[1] // 2), -(-bands.shape[2] // 2)), dtype=np.uint8)
        halve_bands(bands, half)
        bands, factor = half, factor // 2
    return np.ascontiguousarray(np.moveaxis(bands, 0, -1))


def over(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """(h, w, 4) uint8 straight-alpha RGBA: ``top`` laid over ``bottom`` (both (h, w, 4) uint8
    straight alpha, Porter-Duff over); an opaque top pixel stays exactly as it is."""
    ta = top[..., 3:].astype(np.float32) / 255.0
    ba = bottom[..., 3:].astype(np.float32) / 255.0
    alpha = ta + ba * (1.0 - ta)
    rgb = top[..., :3] * ta + bottom[..., :3] * (ba * (1.0 - ta))
    rgb = np.where(alpha > 0, rgb / np.maximum(alpha, 1e-6), 0.0)
    out = np.empty_like(top)
    out[..., :3] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    out[..., 3] = np.clip(np.rint(alpha[..., 0] * 255.0), 0, 255).astype(np.uint8)
    return out


def open_imagery(
    textures: Any,
    scheme: TileScheme,
    tile_size: int = DEFAULT_TILE_SIZE,
    image_format: str = "png",
    minzoom: int = 0,
    maxzoom: int | None = None,
) -> ImageryTiles:
    """ImageryTiles of a texture pyramid folder (or an open TexturePyramid or DetailTextures)."""
    pyramid = open_drape(textures)
    return ImageryTiles(pyramid, scheme, tile_size, image_format, minzoom, maxzoom)
