"""Verify a texture pyramid baked from an image alone (``bake --shading none --image FILE``).

Every level's texels are compared with a reference recomputed here from the image, independently
of the bake's code: GDAL's reprojection of the image onto level 0's grid
(``rasterio.warp.reproject`` in strips of ``STRIP`` rows, at one resampling scale measured
across the grid: the middle row and column of level 0 over the image pixels they span,
``io.warp.warp_scale``, as the bake does), then,
for level k, the alpha-weighted 2^k × 2^k box filter of that reprojection (odd sizes repeating
the last row or column at every halving, as the pyramid does), in float without rounding.
Each texel must be within 1 level per channel: alpha everywhere, colour where both alphas are
non-zero. The reference streams level by level in strips, so memory is a few strips of level 0
whatever the pyramid's size.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import TerrainFormatError
from approxtree.io.warp import RESAMPLINGS, warp_scale
from approxtree.verify.level_file import LevelFile

#: Rows of level 0 reprojected at once (a strip of float32 RGBA: 16 bytes a texel).
STRIP = 128
#: Largest difference per channel allowed between a level and its reference.
TOLERANCE = 1


def _reference_level0(
    image: Path, entry: dict, crs: str | None, resampling: str
) -> Iterator[np.ndarray]:
    """Level 0's reference: (4, ≤ STRIP, cols) float32 strips, premultiplied colour (c · a / 255)
    and alpha, top to bottom."""
    import rasterio
    from affine import Affine
    from rasterio.enums import ColorInterp, Resampling
    from rasterio.warp import reproject

    rows, cols = int(entry["height"]), int(entry["width"])
    transform = Affine(*entry["transform"][:6])
    with rasterio.open(image) as ds:
        interp = list(ds.colorinterp)
        alpha = [i + 1 for i, c in enumerate(interp) if c == ColorInterp.alpha]
        colour = [i for i in range(1, ds.count + 1) if i not in alpha]
        palette = len(colour) == 1 and interp[colour[0] - 1] == ColorInterp.palette
        if len(colour) not in (1, 3) or len(alpha) > 1:
            raise TerrainFormatError(f"{image} is not an RGB, grey or paletted image.")
        lut = np.zeros((256, 4), dtype=np.float32)
        if palette:
            for k, c in ds.colormap(colour[0]).items():
                lut[k] = c
        # Paletted images are sampled nearest (indices do not interpolate), as baked.
        method = Resampling.nearest if palette else Resampling[RESAMPLINGS[resampling]]
        bands = len(colour) + 1
        src_crs = ds.crs
        options: dict[str, Any] = {
            "src_crs": src_crs,
            "dst_crs": crs or src_crs,
            "resampling": method,
            "dst_alpha": bands,
            "init_dest_nodata": False,
            **warp_scale(ds, src_crs, crs, transform, (rows, cols)),
        }
        if alpha:
            options["src_alpha"] = bands
        source = rasterio.band(ds, colour + alpha)
        for r0 in range(0, rows, STRIP):
            n = min(STRIP, rows - r0)
            planes = np.zeros((bands, n, cols), dtype=np.uint8)
            reproject(
                source, planes, dst_transform=transform @ Affine.translation(0, r0), **options
            )
            a = planes[-1].astype(np.float32)
            if palette:
                rgba = np.moveaxis(lut[planes[0]], -1, 0)
                a = np.minimum(a, rgba[3])
                colours = rgba[:3]
            else:
                colours = planes[:-1].astype(np.float32)
                if len(colour) == 1:
                    colours = np.repeat(colours, 3, axis=0)
            out = np.empty((4, n, cols), dtype=np.float32)
            out[:3] = colours * (a / 255.0)
            out[3] = a
            yield out


def _halve(block: np.ndarray) -> np.ndarray:
    """(4, 2m, cols) premultiplied → (4, m, ⌈cols/2⌉): 2 × 2 means, an odd last column
    repeated (premultiplied colour and alpha alike: the alpha-weighted box filter)."""
    if block.shape[2] % 2:
        block = np.concatenate([block, block[:, :, -1:]], axis=2)
    b, r, c = block.shape
    return block.reshape(b, r // 2, 2, c // 2, 2).mean(axis=(2, 4), dtype=np.float32)


def check_image(
    output: Path, entries: list, crs: str | None, image: Path, resampling: str, report: Any
) -> None:
    """Compare every level of the pyramid in ``output`` with the image's reference (module
    docstring), strip by strip: each level's reference rows are compared as soon as they are
    complete and halved on for the next level."""
    check = report.check(
        "image", "every level is the box-filtered reprojection of the source image within 1"
    )
    count = len(entries)
    worst = [0.0] * count
    done = [0] * count
    # A level's odd last row, waiting for the next strip to pair with.
    held: list[np.ndarray | None] = [None] * count
    handles = [LevelFile(output, lv) for lv in entries]

    def take(k: int, strip: np.ndarray) -> None:
        worst[k] = max(worst[k], _compare(handles[k], strip, done[k], k, check))
        done[k] += strip.shape[1]
        if k + 1 == count:
            return
        kept = held[k]
        block = strip if kept is None else np.concatenate([kept, strip], axis=1)
        even = block.shape[1] - block.shape[1] % 2
        held[k] = block[:, even:] if even < block.shape[1] else None
        if even:
            take(k + 1, _halve(block[:, :even]))

    try:
        for strip in _reference_level0(image, entries[0], crs, resampling):
            take(0, strip)
        # An odd last row of a level pairs with itself.
        for k in range(count - 1):
            kept = held[k]
            if kept is not None:
                held[k] = None
                take(k + 1, _halve(np.concatenate([kept, kept], axis=1)))
    finally:
        for h in handles:
            h.close()
    for k, lv in enumerate(entries):
        if done[k] != int(lv["height"]):
            check.fail(f"level {k}", f"{lv['height']} rows", f"{done[k]} rows compared")
    report.figures["image_max_difference"] = worst


def _compare(ds, ref: np.ndarray, r0: int, k: int, check: Any) -> float:
    """Compare premultiplied reference rows ``ref`` (4, n, cols) with rows r0.. of level k;
    record failures; return the largest difference found."""
    from rasterio.windows import Window

    n, cols = ref.shape[1], ref.shape[2]
    if n == 0:
        return 0.0
    got = ds.read(window=Window(0, r0, cols, n)).astype(np.float32)
    if got.shape[0] == 2:
        got = np.concatenate([np.repeat(got[:1], 3, axis=0), got[1:]])
    alpha = np.rint(ref[3])
    colour = np.rint(ref[:3] / np.where(ref[3] > 0, ref[3], 1.0) * 255.0)
    diff_a = np.abs(got[3] - alpha)
    both = (ref[3] > 0) & (got[3] > 0)
    diff_c = np.where(both, np.abs(got[:3] - colour), 0.0).max(axis=0)
    diff = np.maximum(diff_a, diff_c)
    check.items += 1
    bad = diff > TOLERANCE
    if bad.any():
        # One offender per strip: its worst texel, and how many texels are off.
        r, c = np.unravel_index(int(diff.argmax()), diff.shape)
        check.fail(
            f"level {k} texel ({r0 + r}, {c}) of {int(bad.sum())} off in rows {r0}..{r0 + n - 1}",
            f"within {TOLERANCE}",
            float(diff[r, c]),
            float(diff[r, c]),
        )
    return float(diff.max())
