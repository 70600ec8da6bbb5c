"""Verify a texture pyramid folder (``approxtree bake``) against its source terrain.

Read with rasterio tile by tile (512 × 512 texels, the levels' own tiling), so memory is a
few tiles whatever the pyramid's size. Checks:

- ``levels``: every level pyramid.json lists is a file, opens, has the size, bands, dtype and
  georeference listed; sizes halve (rounding up) and texels double level to level;
- ``decode``: every tile of every level decodes;
- ``checksums`` (pyramid format 4, ``tile_crc32c``): each tile's CRC-32C (``crc32c``) of its
  decoded texels, band-sequential C order, edge tiles clipped, equals the listed one;
- ``halving``: each coarser level is, within 1 level per channel, the alpha-weighted 2 × 2 box
  filter of the finer one (odd sizes repeat the last row or column), recomputed here in numpy;
- ``coverage``: level 0 covers the source's domain, in the source's CRS;
- ``hillshade`` (when asked: a plain hillshade bake at gdaldem's defaults): level 0 equals
  ``gdaldem hillshade`` of the source within 1, nodata transparent;
- ``image`` (when given the image of a ``bake --shading none --image FILE``): every level is
  the box-filtered reprojection of the image within 1 (``verify.pyramid_image``).
  pyramid.json records no bake parameters, so without either level 0's content is not checked.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import StoreError
from approxtree.verify.level_file import TILE, LevelFile, open_raster
from approxtree.verify.pyramid_image import check_image
from approxtree.verify.report import VerifyReport


def verify_pyramid(
    output: Path,
    terrain: Any,
    report: VerifyReport,
    hillshade: bool,
    source_path: str | None,
    image: str | None = None,
    resampling: str = "bilinear",
) -> None:
    meta_path = output / "pyramid.json"
    try:
        meta = json.loads(meta_path.read_text())
        entries = list(meta["levels"])
        bands = int(meta["bands"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise StoreError(f"{meta_path} is not a readable pyramid.json: {exc}") from exc
    report.figures.update({"format": meta.get("format"), "levels": len(entries), "bands": bands})
    good = _check_levels(output, entries, bands, meta, report)
    _check_tiles(output, entries, good, report)
    _check_halving(output, entries, good, report)
    if terrain is not None and good and good[0]:
        _check_coverage(entries[0], meta.get("crs"), terrain, report)
        if hillshade:
            _check_hillshade(output, entries[0], terrain, source_path, report)
    if image is not None and good and all(good):
        check_image(output, entries, meta.get("crs"), Path(image), resampling, report)
    if not hillshade and image is None:
        report.not_checked.append(
            "level 0's texels against the source: pyramid.json records no bake parameters "
            "(give --hillshade for a plain hillshade bake at gdaldem's defaults, --image for "
            "an image bake)"
        )
    if "tile_crc32c" not in (entries[0] if entries else {}):
        report.not_checked.append("tile checksums: this pyramid (format < 4) lists none")


def _check_levels(output: Path, entries, bands: int, meta, report) -> list[bool]:
    check = report.check("levels", "every level listed exists, opens and is what is listed")
    good = []
    for k, lv in enumerate(entries):
        check.items += 1
        where = f"level {k} ({lv.get('file')})"
        path = output / str(lv.get("file"))
        if not path.is_file():
            check.fail(where, "a file", "missing")
            good.append(False)
            continue
        try:
            with open_raster(path) as ds:
                shape = (ds.count, ds.height, ds.width)
                dtypes = set(ds.dtypes)
                transform = list(ds.transform)[:6]
        except Exception as exc:
            check.fail(where, "opens", f"{type(exc).__name__}: {exc}"[:120])
            good.append(False)
            continue
        listed = (bands, int(lv["height"]), int(lv["width"]))
        ok = shape == listed and dtypes == {"uint8"}
        if not ok:
            check.fail(where, list(listed), list(shape))
        if not np.allclose(transform, lv["transform"], rtol=1e-12, atol=0):
            check.fail(where, lv["transform"], transform)
            ok = False
        if "bytes" in lv and path.stat().st_size != int(lv["bytes"]):
            check.fail(where, f"{lv['bytes']} bytes", path.stat().st_size)
        ok = _check_deltas(output, k, lv, bands, check) and ok
        good.append(ok)
    # The chain: each level halves the one before, texels twice as large, same origin.
    for k in range(1, len(entries)):
        fine, coarse = entries[k - 1], entries[k]
        size = (-(-int(fine["width"]) // 2), -(-int(fine["height"]) // 2))
        t = np.array(fine["transform"], dtype=np.float64)
        want = [2 * t[0], 2 * t[1], t[2], 2 * t[3], 2 * t[4], t[5]]
        check.items += 1
        if (int(coarse["width"]), int(coarse["height"])) != size or not np.allclose(
            coarse["transform"], want, rtol=1e-12
        ):
            check.fail(f"level {k}", f"half of level {k - 1}", [coarse["width"], coarse["height"]])
    return good


def _check_deltas(output: Path, k: int, lv, bands: int, check) -> bool:
    """Each delta of a level (format 5) is a file, opens, holds its tiles' texels (size,
    bands, georeference) and has its listed bytes."""
    ok = True
    rows, cols = int(lv["height"]), int(lv["width"])
    t = lv["transform"]
    for d in lv.get("deltas", ()):
        check.items += 1
        where = f"level {k} delta ({d.get('file')})"
        path = output / str(d.get("file"))
        try:
            tr0, tr1, tc0, tc1 = (int(v) for v in d["tiles"])
            with open_raster(path) as ds:
                shape = (ds.count, ds.height, ds.width)
                transform = list(ds.transform)[:6]
                dtypes = set(ds.dtypes)
        except Exception as exc:
            check.fail(where, "a file that opens", f"{type(exc).__name__}: {exc}"[:120])
            ok = False
            continue
        r0, c0 = tr0 * TILE, tc0 * TILE
        listed = (bands, min(tr1 * TILE, rows) - r0, min(tc1 * TILE, cols) - c0)
        want = [t[0], t[1], t[2] + c0 * t[0] + r0 * t[1], t[3], t[4], t[5] + c0 * t[3] + r0 * t[4]]
        if shape != listed or dtypes != {"uint8"}:
            check.fail(where, list(listed), list(shape))
            ok = False
        if not np.allclose(transform, want, rtol=1e-12, atol=0):
            check.fail(where, want, transform)
            ok = False
        if path.stat().st_size != int(d.get("bytes", -1)):
            check.fail(where, f"{d.get('bytes')} bytes", path.stat().st_size)
    return ok


def _tiles(lv) -> list[tuple[int, int, int, int]]:
    """(row, col, r0, c0) of every 512 × 512 tile of a level, row-major."""
    rows, cols = int(lv["height"]), int(lv["width"])
    return [
        (i, j, i * TILE, j * TILE) for i in range(-(-rows // TILE)) for j in range(-(-cols // TILE))
    ]


def _read(ds, r0: int, c0: int, rows: int, cols: int) -> np.ndarray:
    from rasterio.windows import Window

    h, w = min(rows, ds.height - r0), min(cols, ds.width - c0)
    return ds.read(window=Window(c0, r0, w, h))


def _check_tiles(output: Path, entries, good: list[bool], report) -> None:
    import crc32c

    decode = report.check("decode", "every tile of every level decodes")
    sums = (
        report.check("checksums", "every tile matches its tile_crc32c")
        if any("tile_crc32c" in lv for lv in entries)
        else None
    )
    for k, lv in enumerate(entries):
        if not good[k]:
            continue
        listed = lv.get("tile_crc32c")
        with LevelFile(output, lv) as ds:
            for i, j, r0, c0 in _tiles(lv):
                decode.items += 1
                where = f"level {k} tile ({i}, {j})"
                try:
                    texels = _read(ds, r0, c0, TILE, TILE)
                except Exception as exc:
                    decode.fail(where, "decodes", f"{type(exc).__name__}: {exc}"[:120])
                    continue
                if sums is None or listed is None:
                    continue
                sums.items += 1
                try:
                    want = int(listed[i][j])
                except (IndexError, TypeError, ValueError):
                    sums.fail(where, "a listed checksum", "none")
                    continue
                got = crc32c.crc32c(np.ascontiguousarray(texels).data)
                if got != want:
                    sums.fail(where, want, got)


def halve(fine: np.ndarray) -> np.ndarray:
    """Alpha-weighted 2 × 2 box filter of (bands, rows, cols) uint8 (alpha last), odd sizes
    repeating the last row or column: (bands, ⌈rows/2⌉, ⌈cols/2⌉) uint8, rounded half to even.
    Colour: Σ c·a / Σ a (0 where all four are transparent); alpha: the mean."""
    b, rows, cols = fine.shape
    f = fine.astype(np.float64)
    if rows % 2:
        f = np.concatenate([f, f[:, -1:]], axis=1)
    if cols % 2:
        f = np.concatenate([f, f[:, :, -1:]], axis=2)
    quads = f.reshape(b, f.shape[1] // 2, 2, f.shape[2] // 2, 2)
    alpha = quads[-1]
    weight = alpha.sum(axis=(1, 3))
    out = np.empty((b, quads.shape[1], quads.shape[3]))
    with np.errstate(invalid="ignore", divide="ignore"):
        for c in range(b - 1):
            colour = (quads[c] * alpha).sum(axis=(1, 3)) / weight
            out[c] = np.where(weight > 0, colour, 0.0)
    out[-1] = weight / 4.0
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _check_halving(output: Path, entries, good: list[bool], report) -> None:
    check = report.check("halving", "each coarser level is the 2 × 2 box filter of the finer")
    for k in range(1, len(entries)):
        if not (good[k] and good[k - 1]):
            continue
        with (
            LevelFile(output, entries[k - 1]) as fine,
            LevelFile(output, entries[k]) as ds,
        ):
            for _, _, r0, c0 in _tiles(entries[k]):
                check.items += 1
                try:
                    mine = _read(ds, r0, c0, TILE, TILE).astype(np.int64)
                    src = _read(fine, 2 * r0, 2 * c0, 2 * TILE, 2 * TILE)
                except Exception:
                    continue  # a decode failure, reported by ``decode``
                want = halve(src).astype(np.int64)[:, : mine.shape[1], : mine.shape[2]]
                diff = np.abs(mine - want)
                if diff.max(initial=0) > 1:
                    at = np.unravel_index(int(diff.argmax()), diff.shape)
                    check.fail(
                        f"level {k} texel ({r0 + at[1]}, {c0 + at[2]}) band {at[0]}",
                        int(want[at]),
                        int(mine[at]),
                        float(diff.max()),
                    )


def _check_coverage(lv, crs, terrain, report) -> None:
    check = report.check("coverage", "level 0 covers the source's domain in its CRS")
    check.items = 1
    t = lv["transform"]
    xs = (t[2], t[2] + t[0] * int(lv["width"]))
    ys = (t[5], t[5] + t[4] * int(lv["height"]))
    d = terrain.domain
    slack = 1e-9 * max(abs(v) for v in (d.xmin, d.xmax, d.ymin, d.ymax, 1.0))
    inside = min(xs) <= d.xmin + slack and max(xs) >= d.xmax - slack
    inside = inside and min(ys) <= d.ymin + slack and max(ys) >= d.ymax - slack
    if not inside:
        check.fail(
            "level 0", [d.xmin, d.ymin, d.xmax, d.ymax], [min(xs), min(ys), max(xs), max(ys)]
        )
    if crs and terrain.crs:
        from pyproj import CRS

        if not CRS.from_user_input(crs).equals(CRS.from_user_input(terrain.crs)):
            check.fail("crs", terrain.crs, crs)


def _check_hillshade(output: Path, lv, terrain, source: str | None, report) -> None:
    if shutil.which("gdaldem") is None or source is None:
        report.not_checked.append("hillshade: gdaldem is not on PATH, or the source is no file")
        return
    if not hasattr(terrain, "transform"):
        # A point cloud or TIN is rasterized by the bake: gdaldem has no raster to shade.
        report.not_checked.append(
            f"hillshade: the source is a {type(terrain).__name__}, not a raster gdaldem can shade"
        )
        return
    check = report.check("hillshade", "level 0 is gdaldem's hillshade of the source within 1")
    check.items = 1
    if not np.allclose(list(terrain.transform)[:6], lv["transform"], rtol=1e-12) or tuple(
        terrain.shape
    ) != (int(lv["height"]), int(lv["width"])):
        check.fail("level 0", "the source's cells as texels", "another texel grid")
        return
    from pyproj import CRS

    # gdaldem's scale for grids in degrees, as the bake takes it (metres per degree).
    geographic = bool(terrain.crs) and CRS.from_user_input(terrain.crs).is_geographic
    scale = ["-s", "111120"] if geographic else []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "hs.tif"
        run = subprocess.run(
            ["gdaldem", "hillshade", "-q", *scale, str(source), str(out)],
            capture_output=True,
            text=True,
            env={**os.environ, "GDAL_PAM_ENABLED": "NO"},
        )
        if run.returncode != 0:
            del report.checks["hillshade"]
            report.not_checked.append(
                f"hillshade: gdaldem cannot read the source ({run.stderr.strip()[:80]})"
            )
            return
        with open_raster(out) as ref_ds, LevelFile(output, lv) as ds:
            for _, _, r0, c0 in _tiles(lv):
                ref = _read(ref_ds, r0, c0, TILE, TILE)[0].astype(np.int64)
                mine = _read(ds, r0, c0, TILE, TILE)
                grey, alpha = mine[0].astype(np.int64), mine[-1]
                bad = ((ref == 0) & (alpha != 0)) | ((ref != 0) & (np.abs(grey - ref) > 1))
                if bad.any():
                    r, c = np.argwhere(bad)[0]
                    check.fail(
                        f"level 0 texel ({r0 + r}, {c0 + c})", int(ref[r, c]), int(grey[r, c])
                    )
