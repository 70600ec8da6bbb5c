"""The Garland & Heckbert test terrains: SCAPE ``.stm`` and PGM (``.pgm``) height images.

STM (no library exists; parsed with numpy): an ASCII header line
``STM <width> <height> <4 order bytes>\\n`` then width × height unsigned 16-bit heights, row 0 =
north. Order bytes 04 03 02 01 mean big-endian, 01 02 03 04 little-endian.
PGM (P2 ASCII or P5 binary) is read with Pillow, which rescales values to 0..255 or 0..65535;
the header's maxval undoes that exactly.
Neither carries a georeference: cell size 1 and row 0 at the top unless cell_size/origin say.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from approxtree.errors import TerrainFormatError
from approxtree.geometry import Grid
from approxtree.io._common import (
    check_cell_size,
    check_crs,
    check_nodata_policy,
    check_origin,
    existing_file,
    make_grid,
    reading,
    resolve_transform,
)

_STM_HEADER = re.compile(rb"STM (\d+) (\d+) (.{4})\n", re.DOTALL)
_STM_ORDER = {b"\x04\x03\x02\x01": ">u2", b"\x01\x02\x03\x04": "<u2"}


def read_stm(
    path: str | os.PathLike,
    *,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
) -> Grid:
    """Read a SCAPE .stm height file as a Grid of heights (height, width) float32."""
    p = existing_file(path)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    with reading(p, "a SCAPE .stm file"):
        with open(p, "rb") as f:
            head = f.read(64)
        width, height, dtype, offset = _stm_header(p, head)
        expected = width * height * 2
        actual = p.stat().st_size - offset
        if actual != expected:
            raise TerrainFormatError(
                f"{p} is {'truncated' if actual < expected else 'longer than its header says'}: "
                f"a {width} × {height} STM needs {expected} bytes of heights after the header, "
                f"the file has {actual}."
            )
        values = np.fromfile(p, dtype=dtype, count=width * height, offset=offset)
    heights = values.reshape(height, width).astype(np.float32)
    transform = resolve_transform(None, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs, None, policy)


def _stm_header(path: Path, head: bytes) -> tuple[int, int, str, int]:
    """(width, height, numpy dtype, byte offset of the heights) from the first bytes."""
    match = _STM_HEADER.match(head)
    if match is None:
        raise TerrainFormatError(
            f"{path} does not start with an STM header 'STM <width> <height> <order>'."
        )
    order = match.group(3)
    if order not in _STM_ORDER:
        raise TerrainFormatError(
            f"{path} has unknown STM byte-order bytes {order.hex(' ')}; expected "
            "04 03 02 01 (big-endian) or 01 02 03 04 (little-endian)."
        )
    return int(match.group(1)), int(match.group(2)), _STM_ORDER[order], match.end()


def read_pgm(
    path: str | os.PathLike,
    *,
    nodata: str = "mask",
    crs: str | None = None,
    cell_size: float | tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
) -> Grid:
    """Read a grayscale PGM (P2 or P5, 8 or 16 bit) as a Grid of heights (rows, cols) float32."""
    p = existing_file(path)
    policy = check_nodata_policy(nodata)
    crs = check_crs(crs)
    cell = check_cell_size(cell_size)
    corner = check_origin(origin)
    with reading(p, "a PGM image"):
        from PIL import Image

        with open(p, "rb") as f:
            maxval = _pgm_maxval(p, f.read(1024))
        with Image.open(p) as image:
            values = np.asarray(image, dtype=np.float64)
            full_scale = 255 if image.mode == "L" else 65535
    # Pillow stretched maxval to full scale with rounding; rounding back is exact.
    if maxval != full_scale:
        values = np.rint(values * maxval / full_scale)
    heights = values.astype(np.float32)
    transform = resolve_transform(None, heights.shape, cell, corner, p)
    return make_grid(heights, transform, crs, None, policy)


def _pgm_maxval(path: Path, head: bytes) -> int:
    """The maxval of a P2/P5 header (magic, width, height, maxval; # starts a comment)."""
    tokens: list[bytes] = []
    for line in head.split(b"\n"):
        tokens += line.split(b"#", 1)[0].split()
        if len(tokens) >= 4:
            break
    if len(tokens) < 4 or tokens[0] not in (b"P2", b"P5") or not tokens[3].isdigit():
        raise TerrainFormatError(
            f"{path} is not a grayscale PGM (expected a 'P2' or 'P5' header with width, height "
            "and maxval)."
        )
    return int(tokens[3])
