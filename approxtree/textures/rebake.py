"""Re-baking: the texture pyramid follows an edit of the terrain, or a new light.

``rebake(folder, terrain, rect)`` re-bakes only the pyramid tiles that an edit of the terrain's
cells inside ``rect`` reaches, on every level, to the texels a fresh ``bake`` of the edited
terrain writes:

1. Level 0 (``reached_texels``): the texels whose height sample reads an edited cell (the cell
   itself on the DEM's own lattice; a resampled lattice interpolates h_T bilinearly, so within
   one cell of it), grown by one texel for the shading kernel's 3 × 3 gradient window. The
   512² tiles they meet are shaded again (``_Texels``) from a window of h_T with one more
   texel of context on every side: the kernel's nodata border ring falls in the context, and
   on the terrain's own border it is the terrain's, as in the bake.
2. Level k + 1: the texels whose 2 × 2 footprint meets the changed texels of level k (the
   changed rectangle halved, rounding outwards); their values are halved in memory from the
   new texels of level k with the bake's own filter (``halve_bands``): level 0 is made over
   the reached texels widened to a multiple of 2^(levels − 1), so every halving pairs the rows
   and columns the bake pairs (``_level_blocks``). The tiles they meet are rewritten: their
   old texels with the new ones pasted over them.
3. All or nothing, without copying a level: each level's rewritten tiles go to a new file of
   their own, a delta ``level{k}.{build}.tif`` holding just those whole tiles (pyramid.py's
   docstring, format 5), flushed to disk; then pyramid.json is replaced in one step
   (``atomic_write``) listing the deltas, the new tile checksums and a new build id, so a
   reader sees the old pyramid or the new one and a kill leaves one of them. Then the files
   no pyramid.json lists go (deltas a newer one covers, levels written whole again; a killed
   re-bake's files go at the start of the next). A level whose base file and deltas together
   pass GROWTH × its size when last written whole, or that would hold more than MAX_DELTAS
   deltas, is written whole again instead (a new file, the same way).

A new water level (``water.WaterLevel``, a flood drawn under the shading) re-bakes the tiles
the texels between the old and the new shore line meet, by the same steps.

What is re-baked whole, through ``bake`` with the pyramid's recipe: a new light (or any other
``shading_options``), and the shadings whose texels depend on far cells (cast shadows, the
curvature weight's spread over the whole grid, Phong and Gouraud on their own lattice).
A thematic layer (``bake(thematic=…)``) is re-blended: the bake records its raster in the
recipe (path, palette, bytes and modification time); a re-bake colours it on the whole lattice
as the bake does (a colour ramp spans the whole raster's values) and blends the re-shaded
tiles over it, and refuses (StoreError) a raster gone or changed since. Images
(``bake(images=…)``) likewise: recorded in the recipe, warped again over the bake's very
strips that hold the re-baked rows (GDAL's warp at an image's edge depends on the chunk),
the window cut out of them. Overlays and water polygons (``bake(overlays=…, water=…)``)
likewise: recorded in the recipe (paths, bytes and times; the overlays' colour, width and
least width in texels), burnt on the whole lattice as the bake burns them (the lines hidden
under the thematic layer's water classes, as the bake hides them) and the window cut out of
them, so its edges hold the bake's texels; at every coarser level the overlays are redrawn
over the halved texels at the level's own texel size, the whole level burnt once and the
re-baked window cut out of it, before that level is halved again (the bake's ``redraw``).

Measured (``benchmarks/bench_update.py --pyramid``, 2 shared cores, load average 4–12, each
re-bake beside a full bake of the same terrain): a 256² edit of an 8192² terrain re-bakes in
61 ms, 3.3 % of the full bake (14–23 % when every level file was copied for the swap).
"""

from __future__ import annotations

import json
import os
import signal
import stat
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.io.atomic import atomic_write
from approxtree.io.gdal import checked_write, no_side_files
from approxtree.kernels.rgba import halve_bands
from approxtree.textures.bake import (
    MIN_OVERLAY_TEXELS,
    OVERLAY_COLOUR,
    WATER_COLOUR,
    OverlayLook,
    bake,
    overlay_lines,
    redraw_overlays,
    texture_lattice,
    thematic_on_lattice,
    thematic_water_mask,
)
from approxtree.textures.base import TextureData
from approxtree.textures.blend import MultiTexture
from approxtree.textures.image import ImageTexture
from approxtree.textures.pyramid import (
    _TAG_BUILD,
    _TAG_LEVEL,
    _TILE,
    OWN_LEVEL_FILE,
    WINDOW_BYTES,
    TexturePyramid,
    _dump_meta,
    _over,
    level_profile,
    tile_row_checksums,
    window_shape,
)
from approxtree.textures.shading import TopographicShading
from approxtree.textures.thematic import ThematicTexture, rasterize_lines
from approxtree.textures.water import WaterLevel, wet

#: Texel rectangle (r0, r1, c0, c1), half-open, in a level's own rows and columns.
TexelRect = tuple[int, int, int, int]
#: A level is written whole again once its file and deltas together pass this many times its
#: size when it was last written whole (``compact_bytes`` in its pyramid.json entry) ...
GROWTH = 2.0
#: ... or it would hold more deltas than this (each is opened and checked with the pyramid).
MAX_DELTAS = 32


@dataclass
class Rebake:
    """What a re-bake wrote.

    pyramid: the pyramid as it is now. tiles: per level, the tiles written; tiles_total: per
    level, the level's tiles. whole: True when the pyramid was baked whole (a new light, a
    shading that is not local). seconds: wall time; copy_seconds: time spent copying level
    files, 0 since re-bakes write deltas instead (kept for the JSON figures' readers).
    """

    pyramid: TexturePyramid
    tiles: list[int]
    tiles_total: list[int]
    whole: bool
    seconds: float
    copy_seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready figures (``approxtree update --textures --json``)."""
        return {
            "tiles": sum(self.tiles),
            "tiles_total": sum(self.tiles_total),
            "tiles_per_level": self.tiles,
            "whole": self.whole,
            "seconds": round(self.seconds, 6),
            "copy_seconds": round(self.copy_seconds, 6),
        }


def rebake(
    pyramid: TexturePyramid | str | os.PathLike,
    terrain: Grid,
    rect: Rect | None = None,
    shading_options: dict[str, Any] | None = None,
    context: Any = None,
    water_level: float | None = None,
) -> Rebake:
    """Re-bake the pyramid baked from ``terrain`` after its cells inside ``rect`` changed.

    pyramid: a TexturePyramid or its folder, baked by ``bake`` (its recipe is in pyramid.json).
    terrain: the edited terrain (same lattice as when baked). rect: the world rectangle of the
    edited cells (on cell edges), or None for the whole pyramid. shading_options: options to
    change (e.g. ``{"azimuth": 200.0}``): the pyramid is re-baked whole with them and the
    recipe keeps them. context: a moderngl context for a whole re-bake of a pyramid whose
    shading was baked with OpenGL (None: numpy, within ±1 grey level of it; tiles re-baked on
    their own are always shaded with numpy). water_level: a new level for a pyramid
    baked with one (``bake(water_level=…)``): the tiles between the old and the new shore line
    are re-baked, and the recipe keeps the level.
    """
    t0 = time.perf_counter()
    if not isinstance(pyramid, TexturePyramid):
        pyramid = TexturePyramid(pyramid)
    recipe = _recipe(pyramid)
    options = {**recipe["shading_options"], **(shading_options or {})}
    old_level = recipe.get("water_level")
    if water_level is not None and old_level is None:
        raise InvalidParameterError(
            f"{pyramid.folder} was baked without a water level; bake it with one first."
        )
    level = old_level if water_level is None else float(water_level)
    transform, shape = texture_lattice(terrain, float(recipe["texel_size"]))
    level0 = pyramid.levels[0]
    if shape != (level0.height, level0.width) or not transform.almost_equals(level0.transform):
        raise InvalidParameterError(
            f"{pyramid.folder} was not baked from this terrain: its level 0 is "
            f"{level0.width} × {level0.height} texels at {tuple(level0.transform)[:6]}, the "
            f"terrain's lattice {shape[1]} × {shape[0]} at {tuple(transform)[:6]}."
        )
    totals = [_tiles_of(lv.height, lv.width) for lv in pyramid.levels]
    thematic = recipe.get("thematic")
    look = OverlayLook(
        tuple(recipe.get("overlay_colour", OVERLAY_COLOUR)),
        recipe.get("overlay_width"),
        float(recipe.get("min_overlay_texels", MIN_OVERLAY_TEXELS)),
    )
    # A new light, or a shading that reads far cells: the whole pyramid, as a bake makes it.
    flood = water_level is not None and level != old_level
    if (
        (rect is None and water_level is None)
        or shading_options
        or not _is_local(recipe["shading"], options)
    ):
        result = bake(
            terrain,
            pyramid.folder,
            shading=recipe["shading"],
            shading_options=options,
            texel_size=float(recipe["texel_size"]),
            max_texture_size=pyramid.max_texture_size,
            gl=bool(recipe["gl"]),
            context=context,
            water_level=level,
            blend=recipe.get("blend", "shade"),
            thematic=None if thematic is None else thematic["path"],
            palette=None if thematic is None else thematic["palette"],
            images=[image["path"] for image in recipe.get("images", [])],
            resampling=recipe.get("resampling", "bilinear"),
            overlays=[line["path"] for line in recipe.get("overlays", [])],
            water=[body["path"] for body in recipe.get("water", [])],
            overlay_colour=tuple(look.colour),
            overlay_width=look.width,
            min_overlay_texels=look.min_texels,
        )
        return Rebake(result.pyramid, totals, totals, True, time.perf_counter() - t0)
    same = shape == terrain.shape and transform.almost_equals(terrain.transform)
    reached = None if rect is None else reached_texels(terrain, rect, transform, shape, same)
    if flood and old_level is not None and level is not None:
        shore = _shore_texels(terrain, transform, shape, same, old_level, level)
        reached = _union(reached, shore)
    levels = pyramid.levels
    tiles = [0] * len(levels)
    folder = pyramid.folder
    meta = json.loads((folder / "pyramid.json").read_text())
    if flood:
        meta["recipe"]["water_level"] = level
        meta["recipe"]["layers"] = [
            f"water-level:{level:g}" if name.startswith("water-level:") else name
            for name in meta["recipe"]["layers"]
        ]
    if reached is None:
        # No texel changed: only a new water level to remember.
        if flood:
            with atomic_write(folder / "pyramid.json") as f:
                f.write(_dump_meta(meta).encode())
        return Rebake(TexturePyramid(folder), tiles, totals, False, time.perf_counter() - t0)
    # Every file keeps its own build id in pyramid.json; the pyramid gets a new one.
    for entry in meta["levels"]:
        entry.setdefault("build", meta["build"])
    meta["build"] = build = uuid.uuid4().hex
    meta["format"] = 5
    # Each level's changed texels: those whose 2 × 2 footprint meets the finer level's.
    changed = [reached]
    for _ in levels[1:]:
        r0, r1, c0, c1 = changed[-1]
        changed.append((r0 // 2, -(-r1 // 2), c0 // 2, -(-c1 // 2)))
    # A killed re-bake's files (never listed) go before this one writes its own.
    remove_unlisted(folder, pyramid.files)
    # The thematic layer's colours on the whole lattice, as the bake makes them (a colour
    # ramp spans the whole raster's values, so no window of it alone gives the same).
    colours = None
    if thematic is not None:
        layer = thematic_on_lattice(
            Path(thematic["path"]), thematic["palette"], transform, shape, terrain.crs
        )
        colours = layer.rgba()
    make = _Texels(terrain, options, level, recipe.get("blend", "shade"), transform, same)
    make.colours = colours
    # Overlay lines and water polygons on the whole lattice, as the bake burns them (a window
    # is cut out of them: the same texels at its edges), and at every coarser level redrawn
    # over the halved texels at the level's own texel size, as the bake redraws them.
    lines = [Path(line["path"]) for line in recipe.get("overlays", [])]
    mask = None
    if lines and thematic is not None:
        mask = thematic_water_mask(layer, thematic["palette"])
    make.vectors = [overlay_lines(p, look, transform, shape, terrain.crs, mask) for p in lines]
    make.vectors += [
        rasterize_lines(Path(body["path"]), transform, shape, terrain.crs, WATER_COLOUR, 0.0)
        for body in recipe.get("water", [])
    ]
    redraw = None
    if lines:

        def redraw(k: int) -> np.ndarray:
            t = transform @ Affine.scale(float(1 << k))
            lv_shape = (levels[k].height, levels[k].width)
            return redraw_overlays(lines, look, k, t, lv_shape, terrain.crs, mask)

    # Images are warped on the window's rows only, at the whole lattice's scale (as the bake).
    make.images = [
        ImageTexture(Path(image["path"]), transform, shape, terrain.crs, recipe["resampling"])
        for image in recipe.get("images", [])
    ]
    blocks = _level_blocks(make, shape, reached, len(levels), redraw)
    try:
        for k in range(len(levels) - 1, -1, -1):
            lv, (where, block) = levels[k], blocks[k]
            # The whole tiles the changed texels meet: the old texels, the new ones over them,
            # into a new file of their own (a delta) or, past GROWTH, the level whole again.
            region = _tile_region(changed[k], lv.height, lv.width)
            r0, r1, c0, c1 = region
            texels = pyramid.read_bands(k, r0, c0, r1 - r0, c1 - c0)
            _paste(texels, region, block, where)
            _write_tiles(pyramid, k, texels, region, build, meta["levels"][k])
            tiles[k] = _tiles_of(r1 - r0, c1 - c0)
        _hook("rebake-written")
        # The commit: pyramid.json names the new files (atomic_write: all or nothing).
        with atomic_write(folder / "pyramid.json") as f:
            f.write(_dump_meta(meta).encode())
    except BaseException:
        # Nothing committed: this re-bake's files (whole or not) go, the old pyramid stays.
        remove_unlisted(folder, pyramid.files)
        raise
    _hook("rebake-committed")
    fresh = TexturePyramid(folder)
    # The files no longer listed: deltas covered by newer ones, levels written whole again.
    remove_unlisted(folder, fresh.files)
    return Rebake(fresh, tiles, totals, False, time.perf_counter() - t0)


def remove_unlisted(folder: Path, listed: set[str]) -> list[str]:
    """Remove the level files of ``folder`` (``OWN_LEVEL_FILE`` names, plain files only, never
    a link) not in ``listed``; returns their names."""
    gone = []
    for name in sorted(os.listdir(folder)):
        if name in listed or not OWN_LEVEL_FILE.match(name):
            continue
        path = folder / name
        if stat.S_ISREG(os.lstat(path).st_mode):
            path.unlink(missing_ok=True)
            gone.append(name)
    return gone


def _hook(stage: str) -> None:
    """Test hook: APPROXTREE_UPDATE_KILL=stage kills this process here (a re-bake's files
    written but not committed, or committed but the old ones not removed)."""
    if os.environ.get("APPROXTREE_UPDATE_KILL") == stage:
        os.kill(os.getpid(), signal.SIGKILL)


def reached_texels(
    terrain: Grid, rect: Rect, transform: Affine, shape: tuple[int, int], same: bool
) -> TexelRect | None:
    """Level-0 texels (r0, r1, c0, c1), half-open, whose shading reads a cell inside ``rect``
    (module doc, step 1); None when the rect misses the lattice."""
    t = terrain.transform
    # The edited cells, half-open, from the rect's corners (on cell edges).
    cols = sorted(((rect.xmin - t.c) / t.a, (rect.xmax - t.c) / t.a))
    rows = sorted(((rect.ymin - t.f) / t.e, (rect.ymax - t.f) / t.e))
    r0, r1 = round(rows[0]), round(rows[1])
    c0, c1 = round(cols[0]), round(cols[1])
    if not same:
        # A texel's height is interpolated from the four data points around its centre: it
        # reads an edited cell when its centre lies within one cell of one (one more cell of
        # slack against round-off), then the 3 × 3 window adds one texel.
        x0, y0 = t @ (c0 - 2, r0 - 2)
        x1, y1 = t @ (c1 + 2, r1 + 2)
        inv = ~transform
        (ca, ra), (cb, rb) = inv @ (x0, y0), inv @ (x1, y1)
        r0, r1 = int(np.floor(min(ra, rb))), int(np.ceil(max(ra, rb)))
        c0, c1 = int(np.floor(min(ca, cb))), int(np.ceil(max(ca, cb)))
    # The 3 × 3 gradient window: one texel more on every side.
    r0, r1 = max(r0 - 1, 0), min(r1 + 1, shape[0])
    c0, c1 = max(c0 - 1, 0), min(c1 + 1, shape[1])
    if r0 >= r1 or c0 >= c1:
        return None
    return r0, r1, c0, c1


def _recipe(pyramid: TexturePyramid) -> dict[str, Any]:
    """The pyramid's recipe, checked to be one a re-bake can repeat (a shading only)."""
    recipe = pyramid.recipe
    if recipe is None:
        raise StoreError(
            f"{pyramid.folder} records no bake recipe (baked before re-bakes existed, or "
            "from an array): bake it again (approxtree bake) to let it follow updates."
        )
    # A thematic layer is re-blended when the bake recorded its raster (``recipe["thematic"]``).
    kept: tuple[str, ...] = ("shading:", "water-level:")
    kept += ("thematic:",) if "thematic" in recipe else ()
    kept += ("image:",) if "images" in recipe else ()
    kept += ("overlay:",) if "overlays" in recipe else ()
    kept += ("water:",) if "water" in recipe else ()
    others = [name for name in recipe["layers"] if not name.startswith(kept)]
    if others or recipe["shading"] is None:
        raise InvalidParameterError(
            f"{pyramid.folder} holds layers a re-bake does not repeat ({', '.join(others)}); "
            "only pyramids of a shading (with a water level, a thematic raster, images, "
            "overlays, water polygons) "
            "follow updates: bake it again (approxtree bake)."
        )
    records = [*recipe.get("images", []), *recipe.get("overlays", []), *recipe.get("water", [])]
    thematic = recipe.get("thematic")
    if thematic is not None:
        records += [thematic] + ([thematic["palette_file"]] if "palette_file" in thematic else [])
    for record in records:
        _check_input(pyramid.folder, record)
    return recipe


def _check_input(folder: Path, record: dict[str, Any]) -> None:
    """StoreError unless the input file a bake recorded is there, of the same bytes and
    modification time (a re-bake re-blends it and must find what the bake read)."""
    path = Path(record["path"])
    try:
        st = path.stat()
    except OSError as exc:
        raise StoreError(
            f"{folder} was baked with {path}, which is gone ({exc.strerror}): bake the "
            "pyramid again (approxtree bake)."
        ) from exc
    if (st.st_size, st.st_mtime_ns) != (record["bytes"], record["mtime_ns"]):
        raise StoreError(
            f"{folder} was baked with {path}, which changed since ({st.st_size} bytes now, "
            f"{record['bytes']} then; or a new modification time): bake the pyramid again "
            "(approxtree bake)."
        )


def _is_local(shading: str, options: dict[str, Any]) -> bool:
    """Whether a texel of this shading reads only the 3 × 3 heights around it."""
    return (
        shading == "topographic"
        and not options.get("shadows", False)
        and not options.get("curvature_weight", 0.0)
    )


def _tiles_of(rows: int, cols: int) -> int:
    """Tiles of a rows × cols block starting on a tile edge."""
    return -(-rows // _TILE) * -(-cols // _TILE)


def _tile_region(texels: TexelRect, rows: int, cols: int) -> TexelRect:
    """The whole tiles (clipped to the level's rows × cols) that ``texels`` meets."""
    r0, r1, c0, c1 = texels
    return (
        r0 // _TILE * _TILE,
        min(-(-r1 // _TILE) * _TILE, rows),
        c0 // _TILE * _TILE,
        min(-(-c1 // _TILE) * _TILE, cols),
    )


class _Texels:
    """The level-0 texels of a rect as the bake makes them: h_T on the lattice over the rect
    and one texel of context on every side, the water layer if any, the shading blended over
    it (``bake``'s layers, on a window of the lattice)."""

    def __init__(
        self,
        terrain: Grid,
        options: dict[str, Any],
        level: float | None,
        blend: str,
        transform: Affine,
        same: bool,
    ) -> None:
        self.terrain, self.options, self.level, self.blend = terrain, options, level, blend
        self.transform, self.same = transform, same
        #: (rows, cols, 4) uint8 of the thematic layer on the whole lattice, or None.
        self.colours: np.ndarray | None = None
        #: The images on the whole lattice, bottom first.
        self.images: list[ImageTexture] = []
        #: The overlay lines, then the water polygons, on the whole lattice (drawn over).
        self.vectors: list[ThematicTexture] = []

    def __call__(self, region: TexelRect, shape: tuple[int, int]) -> np.ndarray:
        """(bands, rows, cols) uint8 texels of ``region`` (half-open rows and columns)."""
        r0, r1, c0, c1 = region
        a, b = max(r0 - 1, 0), min(r1 + 1, shape[0])
        c, d = max(c0 - 1, 0), min(c1 + 1, shape[1])
        z = _lattice_heights(self.terrain, self.transform, shape, self.same, (a, b, c, d))
        t = self.transform @ Affine.translation(c, a)
        window = Grid(z, t, self.terrain.crs, allow_empty=True)
        # The bake's layers on the window: thematic, water, then the shading blended over
        # the colour layers below it (the others drawn "over").
        layers: list[TextureData] = []
        for image in self.images:
            # The very strips the bake warps (whole rows, cut where its strips are: GDAL's
            # warp of an image's edge depends on the chunk), then the window out of them.
            step = window_shape(image.shape[1], 4, WINDOW_BYTES)[0]
            start, stop = a // step * step, min(-(-b // step) * step, image.shape[0])
            strip = np.concatenate(list(image.band_strips(step, start, stop)), axis=1)
            rgba = np.moveaxis(strip[:, a - start : b - start, c:d], 0, -1)
            layers.append(_Colours(rgba, t, self.terrain.crs))
        if self.colours is not None:
            layers.append(_Colours(self.colours[a:b, c:d], t, self.terrain.crs))
        if self.level is not None:
            layers.append(WaterLevel(window, self.level, WATER_COLOUR))
        colour_layers = len(layers)
        layers.append(TopographicShading(window, **self.options))
        for vector in self.vectors:
            layers.append(
                ThematicTexture(
                    vector.values[a:b, c:d],
                    t,
                    vector.mapper,
                    crs=self.terrain.crs,
                    valid=vector.valid[a:b, c:d],
                )
            )
        modes = ["over"] * (len(layers) - 1)
        if colour_layers:
            modes[colour_layers - 1] = self.blend
        texture = layers[0] if len(layers) == 1 else MultiTexture(layers, modes)
        block = np.concatenate([s.copy() for s in texture.level_strips(512)], axis=1)
        return np.ascontiguousarray(block[:, r0 - a : r1 - a, c0 - c : c1 - c])


class _Colours(TextureData):
    """A window of a colour layer already made on the whole lattice."""

    def __init__(self, rgba: np.ndarray, transform: Affine, crs: str | None) -> None:
        self._rgba, self.transform, self.crs = rgba, transform, crs
        self.shape = (int(rgba.shape[0]), int(rgba.shape[1]))

    def rgba(self) -> np.ndarray:
        return np.ascontiguousarray(self._rgba)


def _lattice_heights(
    terrain: Grid, transform: Affine, shape: tuple[int, int], same: bool, rect: TexelRect
) -> np.ndarray:
    """(rows, cols) h_T at the texel centres of ``rect`` of the lattice, as the bake samples
    them: the grid's own heights, or interpolated at the very same centres (sliced from the
    whole lattice's coordinates, not recomputed) as float32."""
    a, b, c, d = rect
    if same:
        return np.asarray(terrain.heights[a:b, c:d])
    xs = transform.c + (np.arange(shape[1]) + 0.5) * transform.a
    ys = transform.f + (np.arange(shape[0]) + 0.5) * transform.e
    return terrain.height_at(xs[None, c:d], ys[a:b, None]).astype(np.float32)


def _shore_texels(
    terrain: Grid,
    transform: Affine,
    shape: tuple[int, int],
    same: bool,
    old: float,
    new: float,
) -> TexelRect | None:
    """Level-0 texels (r0, r1, c0, c1) bounding those that are wet under one water level and
    dry under the other (a pass over the lattice's heights, strip by strip); None if none."""
    rows: list[int] = []
    cols = np.zeros(shape[1], dtype=bool)
    for r0 in range(0, shape[0], 512):
        r1 = min(r0 + 512, shape[0])
        z = _lattice_heights(terrain, transform, shape, same, (r0, r1, 0, shape[1]))
        changed = wet(z, old) != wet(z, new)
        hit = np.flatnonzero(changed.any(axis=1))
        if hit.size:
            rows += [r0 + int(hit[0]), r0 + int(hit[-1])]
            cols |= changed.any(axis=0)
    if not rows:
        return None
    hit = np.flatnonzero(cols)
    return min(rows), max(rows) + 1, int(hit[0]), int(hit[-1]) + 1


def _union(a: TexelRect | None, b: TexelRect | None) -> TexelRect | None:
    """The bounding rect of two texel rects (either may be None)."""
    if a is None or b is None:
        return a or b
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


def _level_blocks(
    make: _Texels,
    shape: tuple[int, int],
    reached: TexelRect,
    levels: int,
    redraw: Callable[[int], np.ndarray] | None = None,
) -> list[tuple[TexelRect, np.ndarray]]:
    """Per level, a texel rect holding the changed texels and its (bands, rows, cols) new
    texels: level 0 shaded over the reached texels widened to multiples of 2^(levels − 1),
    each next level its halving in memory (the bake's filter; the widening keeps every
    halving on even rows and columns, or on the level's odd last one, as the bake pairs them)
    with ``redraw(k)`` (the (rows, cols, 4) overlay of the whole level k) drawn over it
    before it is halved again, as the bake writes and halves it."""
    step = 1 << (levels - 1)
    r0, r1, c0, c1 = reached
    rect = (
        r0 // step * step,
        min(-(-r1 // step) * step, shape[0]),
        c0 // step * step,
        min(-(-c1 // step) * step, shape[1]),
    )
    block = make(rect, shape)
    out = [(rect, block)]
    for _ in range(levels - 1):
        r0, r1, c0, c1 = rect
        rect = (r0 // 2, -(-r1 // 2), c0 // 2, -(-c1 // 2))
        half = np.empty((block.shape[0], rect[1] - rect[0], rect[3] - rect[2]), dtype=np.uint8)
        halve_bands(block, half)
        if redraw is not None:
            half = _over(half, redraw(len(out))[rect[0] : rect[1], rect[2] : rect[3]])
        out.append((rect, half))
        block = half
    return out


def _paste(texels: np.ndarray, region: TexelRect, block: np.ndarray, rect: TexelRect) -> None:
    """Copy the part of ``block`` (the texels of ``rect``) inside ``region`` into ``texels``
    (the texels of ``region``)."""
    r0, r1 = max(region[0], rect[0]), min(region[1], rect[1])
    c0, c1 = max(region[2], rect[2]), min(region[3], rect[3])
    # No overlap: nothing to copy (and the slices below would wrap around).
    if r0 >= r1 or c0 >= c1:
        return
    texels[:, r0 - region[0] : r1 - region[0], c0 - region[2] : c1 - region[2]] = block[
        :, r0 - rect[0] : r1 - rect[0], c0 - rect[2] : c1 - rect[2]
    ]


def _write_tiles(
    pyramid: TexturePyramid, k: int, block: np.ndarray, region: TexelRect, build: str, entry: dict
) -> Path:
    """Write the (bands, rows, cols) texels of ``region`` (whole tiles) of level k into a new
    file ``level{k}.{build}.tif``: a delta holding those tiles, or the level whole (its other
    texels read from the pyramid) once the level's files pass GROWTH × its size when last
    written whole or hold MAX_DELTAS deltas. Updates the level's pyramid.json ``entry``
    (tile checksums, deltas or file, bytes); returns the new file."""
    r0, r1, c0, c1 = region
    lv = pyramid.levels[k]
    # The tiles' checksums, as the bake computes them: decoded texels, tile by tile.
    for i, start in enumerate(range(0, r1 - r0, _TILE)):
        sums = tile_row_checksums(block[:, start : start + _TILE])
        entry["tile_crc32c"][r0 // _TILE + i][c0 // _TILE : c0 // _TILE + len(sums)] = sums
    path = pyramid.folder / f"level{k}.{build}.tif"
    tiles = [r0 // _TILE, -(-r1 // _TILE), c0 // _TILE, -(-c1 // _TILE)]
    _write_file(path, block, lv.transform @ Affine.translation(c0, r0), pyramid.crs, build, k)
    # Deltas the new one covers whole hold no tile a read still takes: dropped.
    deltas = [d for d in entry.get("deltas", []) if not _covers(tiles, d["tiles"])]
    deltas.append({"file": path.name, "build": build, "tiles": tiles, "bytes": _size(path)})
    compact = int(entry.setdefault("compact_bytes", entry["bytes"]))
    total = int(entry["bytes"]) + sum(int(d["bytes"]) for d in deltas)
    if total <= GROWTH * compact and len(deltas) <= MAX_DELTAS:
        entry["deltas"] = deltas
        return path
    # Past GROWTH: the level whole again, tile row by tile row (the old texels as read).
    rows = []
    for t0 in range(0, lv.height, _TILE):
        n = min(_TILE, lv.height - t0)
        texels = pyramid.read_bands(k, t0, 0, n, lv.width)
        _paste(texels, (t0, t0 + n, 0, lv.width), block, region)
        rows.append(texels)
    _write_file(path, np.concatenate(rows, axis=1), lv.transform, pyramid.crs, build, k)
    size = _size(path)
    entry.update(file=path.name, build=build, bytes=size, compact_bytes=size, deltas=[])
    return path


def _covers(outer: list[int], inner: list[int]) -> bool:
    """Whether the tile rectangle ``outer`` (tr0, tr1, tc0, tc1) holds all of ``inner``."""
    return (
        outer[0] <= inner[0]
        and inner[1] <= outer[1]
        and outer[2] <= inner[2]
        and (inner[3] <= outer[3])
    )


def _write_file(
    path: Path, block: np.ndarray, transform: Affine, crs: str | None, build: str, k: int
) -> None:
    """Write (bands, rows, cols) texels as a level file (the bake's tiling, compression and
    tags) at ``path``, flushed to disk before it returns (the commit that names it follows)."""
    import rasterio

    bands, rows, cols = block.shape
    profile = level_profile(rows, cols, bands, transform, crs)
    with checked_write(path), no_side_files(), rasterio.open(path, "w", **profile) as ds:
        ds.update_tags(**{_TAG_BUILD: build, _TAG_LEVEL: str(k)})
        ds.write(block)
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _size(path: Path) -> int:
    return path.stat().st_size


__all__ = ["Rebake", "reached_texels", "rebake"]
