"""Baking: a terrain's shading, thematic layers and vector overlays into a texture pyramid.

The texture lattice covers the terrain's grid at the chosen texel size (by default the finest
of the DEM's cell and the thematic raster's cell). Shading at a finer texel size than the DEM
is computed from h_T resampled onto the texture lattice, so the shading has the geometry
resolution the texture needs (core paper, 5.3). Images (RGB, grey, paletted, in any CRS) are
warped onto the lattice by GDAL strip by strip (``image``), thematic rasters resampled onto it
(nearest for class tables, bilinear for continuous fields), vector layers rasterized, and the
layers blended in the order images (the first at the bottom, each over the one before) ·
thematic (over the images) · shading (with the blend mode), then overlays on top.

Topographic shading is baked offscreen with OpenGL (``gl_bake``, tiled, section 5.3) on the
context the caller passes (``approxtree.render.context.create_context``; the CLI makes one),
and with the numpy kernel without one: both give gdaldem's values within ±1 grey level. Phong
and Gouraud shading use numpy.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rasterize import rasterize
from approxtree.io._common import reading
from approxtree.io.gdal import no_side_files
from approxtree.io.output_path import check_output_folder
from approxtree.progress import ProgressCallback
from approxtree.textures.bake_budget import check_bake_size
from approxtree.textures.base import TextureData
from approxtree.textures.blend import BLEND_MODES, MultiTexture
from approxtree.textures.image import ImageTexture, image_resolution
from approxtree.textures.pyramid import TexturePyramid, check_pyramid_target
from approxtree.textures.shading import GouraudShading, PhongShading, TopographicShading
from approxtree.textures.thematic import (
    LEGENDS,
    WATER_CLASSES,
    ClassTable,
    ColourRamp,
    ColourReliefFile,
    ThematicTexture,
    rasterize_lines,
)
from approxtree.textures.water import WaterLevel

#: Overlay lines (streams, roads) by default: a clear blue, and their least width in texels.
OVERLAY_COLOUR = (40, 100, 200, 255)
MIN_OVERLAY_TEXELS = 2.0
#: Water polygons: the softened NLCD open-water blue.
WATER_COLOUR = (110, 148, 190, 255)

#: Texels of h_T resampled at a time onto the texture lattice.
RESAMPLE_TEXELS = 2**20

SHADINGS = {"topographic": TopographicShading, "phong": PhongShading, "gouraud": GouraudShading}


@dataclass
class BakeResult:
    """What a bake wrote: the pyramid and its figures."""

    pyramid: TexturePyramid
    seconds: float
    layers: list[str] = field(default_factory=list)
    #: True when the shading was baked with OpenGL, False for numpy (or no shading).
    gl: bool = False

    def figures(self) -> dict[str, Any]:
        """levels, sizes, bytes, seconds (the figures of ``approxtree bake --json``)."""
        return {
            "levels": len(self.pyramid),
            "sizes": [[lv.width, lv.height] for lv in self.pyramid.levels],
            "bytes": self.pyramid.nbytes,
            "seconds": round(self.seconds, 4),
            "layers": self.layers,
            "gl": self.gl,
            "folder": str(self.pyramid.folder),
        }


def texture_lattice(grid: Grid, texel: float) -> tuple[Affine, tuple[int, int]]:
    """Transform and (rows, cols) of square texels of size ``texel`` over the grid's cells."""
    t = grid.transform
    width = abs(t.a) * grid.width
    height = abs(t.e) * grid.height
    cols = max(1, round(width / texel))
    rows = max(1, round(height / texel))
    return Affine(width / cols * np.sign(t.a), 0, t.c, 0, height / rows * np.sign(t.e), t.f), (
        rows,
        cols,
    )


def _resample_heights(grid: Grid, transform: Affine, shape: tuple[int, int]) -> Grid:
    """h_T sampled at the texel centres of a lattice, as a Grid on that lattice."""
    rows, cols = shape
    xs = transform.c + (np.arange(cols) + 0.5) * transform.a
    ys = transform.f + (np.arange(rows) + 0.5) * transform.e
    # Strip by strip: h_T's float64 temporaries (~50 bytes a texel) never span the lattice.
    z = np.empty(shape, dtype=np.float32)
    step = max(1, RESAMPLE_TEXELS // cols)
    for r0 in range(0, rows, step):
        z[r0 : r0 + step] = grid.height_at(xs[None, :], ys[r0 : r0 + step, None])
    return Grid(z, transform=transform, crs=grid.crs)


def thematic_on_lattice(
    path: Path, palette: str | None, transform: Affine, shape: tuple[int, int], crs: str | None
) -> ThematicTexture:
    """A thematic raster resampled onto the lattice with the mapper the palette names: a
    legend of ``LEGENDS`` (softened), a colour file, a matplotlib colormap, or None for the
    raster's embedded colour table, softened."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    legend = palette in LEGENDS
    src = ThematicTexture.from_raster(path, mapper=ColourRamp() if palette and not legend else None)
    if palette is None:
        mapper = src.mapper.softened() if isinstance(src.mapper, ClassTable) else src.mapper
    elif legend:
        mapper = ClassTable.legend(palette)
    elif Path(palette).is_file():
        mapper = ColourReliefFile(palette)
    else:
        mapper = ColourRamp(palette)
    classes = isinstance(mapper, ClassTable)
    source = np.where(src.valid, src.values, np.nan).astype(np.float64)
    # Class codes that float32 holds exactly (any raster of small integer classes) are taken
    # nearest in half the bytes; continuous fields are interpolated in float64.
    exact32 = classes and np.array_equal(source.astype(np.float32), source, equal_nan=True)
    values = np.full(shape, np.nan, dtype=np.float32 if exact32 else np.float64)
    with reading(path, "a thematic raster"), no_side_files(), rasterio.open(path) as ds:
        dst_crs = crs or (ds.crs.to_string() if ds.crs else None)
        reproject(
            source=source.astype(values.dtype),
            destination=values,
            src_transform=src.transform,
            src_crs=ds.crs,
            dst_transform=transform,
            dst_crs=dst_crs or ds.crs,
            src_nodata=np.nan,
            dst_nodata=np.nan,
            resampling=Resampling.nearest if classes else Resampling.bilinear,
        )
    return ThematicTexture(values, transform, mapper, crs=crs, valid=np.isfinite(values))


def _coarsen(mask: np.ndarray, level: int, shape: tuple[int, int]) -> np.ndarray:
    """(rows, cols) of a level: True where any level-0 texel under it is True."""
    k = 1 << level
    rows, cols = mask.shape
    padded = np.zeros((shape[0] * k, shape[1] * k), dtype=bool)
    padded[:rows, :cols] = mask
    return np.asarray(padded.reshape(shape[0], k, shape[1], k).any(axis=(1, 3)))


def thematic_water_mask(thematic: ThematicTexture, palette: str | None) -> np.ndarray | None:
    """(rows, cols) bool: texels of the thematic layer's water classes (the legend's, or the
    classes of a colour table coloured blue), or None when it has none."""
    mapper = thematic.mapper
    if not isinstance(mapper, ClassTable):
        return None
    if palette in WATER_CLASSES:
        water = WATER_CLASSES[palette]
    else:
        water = tuple(k for k, c in mapper.colours.items() if c[2] >= c[1] and c[2] > c[0] + 60)
    if not water:
        return None
    values = np.where(thematic.valid, thematic.values, np.nan)
    return np.isin(values, np.array(water, dtype=np.float64))


def bake(
    terrain: GeometryData,
    folder: str | os.PathLike,
    shading: str | None = "topographic",
    shading_options: dict[str, Any] | None = None,
    thematic: str | os.PathLike | None = None,
    palette: str | None = None,
    overlays: list[str | os.PathLike] | None = None,
    blend: str = "shade",
    texel_size: float | None = None,
    max_texture_size: int = 4096,
    gl: bool = True,
    context: Any = None,
    tile_size: int | None = None,
    overlay_colour: tuple[int, ...] = OVERLAY_COLOUR,
    overlay_width: float | None = None,
    min_overlay_texels: float = MIN_OVERLAY_TEXELS,
    water: list[str | os.PathLike] | None = None,
    progress: ProgressCallback | None = None,
    images: list[str | os.PathLike] | None = None,
    resampling: str = "bilinear",
    water_level: float | None = None,
) -> BakeResult:
    """Bake the terrain's textures into a pyramid in ``folder`` and return what was written.

    terrain: a Grid, or any terrain (TIN, point cloud), rasterized first (``rasterize``).

    shading: "topographic", "phong", "gouraud" or None; shading_options: keyword arguments of
    that shading class. thematic: a raster of classes or values; palette: a land-cover legend
    ("nlcd", "landclass96"), a gdaldem colour file or a matplotlib colormap name (None: the
    raster's embedded colour table, softened). overlays: vector layers (roads, rivers) drawn on
    top, overlay_colour RGB(A) 0..255, overlay_width world units (None: none asked), at least
    ``min_overlay_texels`` texels wide so that they survive the hardware mipmaps of an
    overview; the water classes of the thematic layer and the ``water`` polygon layers are
    drawn over them (a stream does not cross a lake). images: rasters GDAL reads (RGB, RGBA,
    grey, grey + alpha, paletted; any CRS) warped onto the lattice with ``resampling`` (a
    name of ``io.warp.RESAMPLINGS``), the first at the bottom, each drawn over the one before,
    the thematic layer over them. water_level: a flood, the texels of h_T below it in the
    water colour over the thematic layer (``water.WaterLevel``). blend: how shading combines
    with the images, thematic layer and water below it ("shade" keeps their colour on flat
    ground). The layers, shading options, texel size and water level are kept in
    pyramid.json (``TexturePyramid.recipe``) for ``rebake``.
    gl: bake topographic shading with OpenGL on ``context`` (a moderngl Context, e.g.
    ``approxtree.render.context.create_context()``; None: numpy; tile_size: forced tile
    side, see ``gl_hillshade``); False always uses numpy. progress(done, total): texel rows
    of the pyramid written, all levels together, after each strip (``approxtree.progress``;
    the numpy shading is computed strip by strip, an OpenGL one before the first strip).
    """
    t0 = time.perf_counter()
    # The pyramid's folder must be writable before any work (its parents are never created).
    check_output_folder(folder, "texture pyramid folder")
    # A TIN or point cloud is shaded from its heights sampled on a lattice (at the texel size,
    # else at its mean point spacing); outside its triangles the texture is transparent.
    if not isinstance(terrain, Grid):
        terrain = rasterize(terrain, texel_size)
    if shading is not None and shading not in SHADINGS:
        raise InvalidParameterError(f"Unknown shading {shading!r}; choose one of {list(SHADINGS)}.")
    if blend not in BLEND_MODES:
        raise InvalidParameterError(
            f"Unknown blend mode {blend!r}; choose one of {list(BLEND_MODES)}."
        )
    image_paths = [Path(p) for p in images or []]
    if shading is None and thematic is None and not image_paths and water_level is None:
        raise InvalidParameterError(
            "Nothing to bake: give a shading, a thematic raster or an image."
        )
    if texel_size is not None and not (np.isfinite(texel_size) and texel_size > 0):
        raise InvalidParameterError(
            f"texel_size must be a positive number of world units, got {texel_size!r}."
        )
    # A bake replaces the whole folder: refuse one holding other files before the work.
    check_pyramid_target(folder)
    thematic_path = Path(thematic) if thematic is not None else None
    if thematic_path is not None and not thematic_path.is_file():
        raise TerrainFormatError(f"Thematic raster {thematic_path} does not exist.")
    for image in image_paths:
        if not image.is_file():
            raise TerrainFormatError(f"Image {image} does not exist.")
    # Texel size: as asked, else the finest of the DEM cell and the thematic cell.
    texel = texel_size or min(terrain.cell_size)
    if texel_size is None and thematic_path is not None:
        import rasterio

        with (
            reading(thematic_path, "a thematic raster"),
            no_side_files(),
            rasterio.open(thematic_path) as ds,
        ):
            texel = min(texel, *ds.res)
    if texel_size is None:
        for image in image_paths:
            texel = min(texel, image_resolution(image, terrain.crs))
    transform, shape = texture_lattice(terrain, texel)
    # Refuse at once what this machine cannot bake (a texel far below the DEM's cell).
    same = shape == terrain.shape and transform.almost_equals(terrain.transform)
    vectors = [*(overlays or []), *(water or [])]
    check_bake_size(
        shape,
        texel,
        min(terrain.cell_size),
        _budget_layers(terrain, same, shading, gl, thematic_path, vectors)
        + ["image"] * len(image_paths)
        + ["thematic"] * (water_level is not None),
        2
        if thematic_path is None and not vectors and not image_paths and water_level is None
        else 4,
        max_texture_size,
        folder,
    )
    used_gl = False
    crs = terrain.crs
    # h_T on the texture lattice (shaded, and compared with the water level), made first: a
    # terrain rasterized here is then let go before the thematic layer is resampled.
    on_lattice = None
    if shading is not None or water_level is not None:
        on_lattice = terrain if same else _resample_heights(terrain, transform, shape)
    del terrain
    layers: list[TextureData] = []
    names: list[str] = []
    thematic_layer = None
    # Images first (each opened and checked now, warped strip by strip while the pyramid is
    # written), the thematic layer over them.
    for image in image_paths:
        layers.append(ImageTexture(image, transform, shape, crs, resampling))
        names.append(f"image:{image.name}")
    if thematic_path is not None:
        thematic_layer = thematic_on_lattice(thematic_path, palette, transform, shape, crs)
        layers.append(thematic_layer)
        names.append(f"thematic:{thematic_path.name}")
    if water_level is not None and on_lattice is not None:
        layers.append(WaterLevel(on_lattice, water_level, WATER_COLOUR))
        names.append(f"water-level:{water_level:g}")
    # The shading blends with the colour layers below it (images, thematic, water), if any.
    colour_layers = len(layers)
    if shading is not None and on_lattice is not None:
        options = shading_options or {}
        texture = SHADINGS[shading](on_lattice, **options)
        if gl and shading == "topographic":
            used_gl, texture = _gl_shading(texture, options, context, tile_size)
        layers.append(texture)
        names.append(f"shading:{shading}")
    # Overlays: at least min_overlay_texels wide; water (thematic classes, polygons) over them.
    look = OverlayLook(tuple(overlay_colour), overlay_width, min_overlay_texels)
    water_mask = None
    if thematic_layer is not None and overlays:
        water_mask = thematic_water_mask(thematic_layer, palette)
    for path in overlays or []:
        layers.append(overlay_lines(Path(path), look, transform, shape, crs, water_mask))
        names.append(f"overlay:{Path(path).name}")
    for path in water or []:
        layers.append(rasterize_lines(path, transform, shape, crs, WATER_COLOUR, 0.0))
        names.append(f"water:{Path(path).name}")
    modes = ["over"] * (len(layers) - 1)
    if shading is not None and colour_layers:
        modes[colour_layers - 1] = blend
    texture = layers[0] if len(layers) == 1 else MultiTexture(layers, modes)
    # Coarser levels redraw the overlays at their own texel size (least width kept there).
    redraw = None
    if overlays:

        def redraw(level: int, t: Affine, level_shape: tuple[int, int]) -> np.ndarray:
            paths = [Path(p) for p in overlays]
            return redraw_overlays(paths, look, level, t, level_shape, crs, water_mask)

    # What a re-bake (``rebake``) repeats: the layers and the shading with its options.
    recipe: dict[str, Any] = {
        "layers": names,
        "shading": shading,
        "shading_options": {
            k: v.item() if isinstance(v, np.generic) else v
            for k, v in (shading_options or {}).items()
        },
        "texel_size": float(texel),
        "gl": used_gl,
        "water_level": None if water_level is None else float(water_level),
        "blend": blend,
    }
    # The images and thematic raster a re-bake re-blends under the shading: where, how
    # warped or coloured, their size and time, so that a re-bake refuses one changed since.
    if image_paths:
        recipe["images"] = [input_record(image) for image in image_paths]
        recipe["resampling"] = resampling
    # The vector layers too: a re-bake draws them over the re-baked texels of every level.
    if overlays:
        recipe["overlays"] = [input_record(Path(p)) for p in overlays]
        recipe["overlay_colour"] = [int(v) for v in overlay_colour]
        recipe["overlay_width"] = None if overlay_width is None else float(overlay_width)
        recipe["min_overlay_texels"] = float(min_overlay_texels)
    if water:
        recipe["water"] = [input_record(Path(p)) for p in water]
    if thematic_path is not None:
        recipe["thematic"] = {"palette": palette, **input_record(thematic_path)}
        if palette is not None and Path(palette).is_file():
            recipe["thematic"]["palette_file"] = input_record(Path(palette))
    pyramid = TexturePyramid.build(
        texture,
        folder,
        max_texture_size=max_texture_size,
        level_overlay=redraw,
        progress=progress,
        recipe=recipe,
    )
    return BakeResult(pyramid, time.perf_counter() - t0, names, used_gl)


@dataclass(frozen=True)
class OverlayLook:
    """How overlay lines are drawn: colour RGB(A) 0..255, width in world units (None: none
    asked) and the least width in texels of the level they are drawn on."""

    colour: tuple[int, ...] = OVERLAY_COLOUR
    width: float | None = None
    min_texels: float = MIN_OVERLAY_TEXELS

    def width_at(self, t: Affine) -> float:
        """The lines' width in world units on a lattice of transform ``t``."""
        return max(self.width or 0.0, self.min_texels * max(abs(t.a), abs(t.e)))


def overlay_lines(
    path: Path,
    look: OverlayLook,
    transform: Affine,
    shape: tuple[int, int],
    crs: str | None,
    water_mask: np.ndarray | None,
) -> ThematicTexture:
    """An overlay layer on level 0's lattice (``shape``): its lines, transparent under the
    (rows, cols) ``water_mask`` if any."""
    line = rasterize_lines(path, transform, shape, crs, look.colour, look.width_at(transform))
    if water_mask is not None:
        line.valid = line.valid & ~water_mask
    return line


def redraw_overlays(
    paths: list[Path],
    look: OverlayLook,
    level: int,
    t: Affine,
    level_shape: tuple[int, int],
    crs: str | None,
    water_mask: np.ndarray | None,
) -> np.ndarray:
    """(rows, cols, 4) uint8: the overlay lines drawn on pyramid level ``level`` (transform
    ``t``, ``level_shape``) at its own texel size, the last on top, transparent where none
    is and under the level-0 ``water_mask`` (rows0, cols0) coarsened to the level."""
    out = np.zeros((*level_shape, 4), dtype=np.uint8)
    for path in paths:
        line = rasterize_lines(path, t, level_shape, crs, look.colour, look.width_at(t))
        if water_mask is not None:
            line.valid = line.valid & ~_coarsen(water_mask, level, level_shape)
        rgba = line.rgba()
        out = np.where(rgba[..., 3:] > 0, rgba, out)
    return out


def input_record(path: Path) -> dict[str, Any]:
    """An input file as a recipe keeps it: its absolute path, bytes and modification time."""
    st = path.stat()
    return {"path": str(path.resolve()), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def _budget_layers(
    terrain: Grid, same: bool, shading: str | None, gl: bool, thematic: Path | None, vectors: list
) -> list[str]:
    """The ``bake_budget.BYTES_PER_TEXEL`` keys of a bake: its shading (on the DEM's lattice,
    streamed from a windowed raster, or on a resampled one), thematic layer and overlays."""
    layers = []
    if shading is not None:
        if not same:
            layers.append("resampled")
        if shading != "topographic":
            layers.append(shading)
        elif same:
            streamed = getattr(terrain, "is_windowed", False) and not gl
            layers.append("streamed" if streamed else "topographic")
    if thematic is not None:
        layers.append("thematic")
    layers += ["overlay"] * len(vectors)
    return layers


def _gl_shading(
    shading: TopographicShading, options: dict[str, Any], context: Any, tile_size: int | None
) -> tuple[bool, TextureData]:
    """(True, the shading computed with OpenGL) or, without a context, (False, ``shading``)."""
    from approxtree.errors import ContextUnavailableError
    from approxtree.textures.gl_bake import GLTopographicShading

    if context is None:
        return False, shading
    on_gpu = GLTopographicShading(shading.terrain, context=context, tile_size=tile_size, **options)
    try:
        # Computed now, so a missing context falls back before the pyramid is written.
        shade = on_gpu.shade()
    except ContextUnavailableError:
        return False, shading
    return True, _Precomputed(shading, shade)


class _Precomputed(TextureData):
    """A shading texture whose grey levels were already computed."""

    def __init__(self, like: TextureData, shade: np.ndarray) -> None:
        self.transform, self.shape, self.crs = like.transform, like.shape, like.crs
        self._shade = shade

    def rgba(self) -> np.ndarray:
        from approxtree.textures.base import grey_to_rgba

        return grey_to_rgba(self._shade)

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        from approxtree.textures.base import grey_strips

        return grey_strips(self._shade, rows)

    #: Grey levels: the pyramid stores grey and alpha.
    bands = 2

    def level_strips(self, rows: int) -> Iterator[np.ndarray]:
        from approxtree.textures.base import grey_alpha_strips

        return grey_alpha_strips(self._shade, rows)
