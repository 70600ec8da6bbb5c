"""What a bake will take, checked before it starts: texels, memory, disk, the format's limits.

A texel size far below the DEM's cell asks for a texture no machine holds (``--texel 1e-6``
over a 15 km DEM: 2 · 10^20 texels). ``check_bake_size`` refuses such a request at once, with
what it would take and the texel size that fits, instead of a MemoryError after the work has
begun. Memory is counted in bytes per level-0 texel held while baking, measured with peak RSS
on bakes of 22–67 million texels (NC DEM at 3 m and 1.5 m, a fractal 8192²; see
``BYTES_PER_TEXEL``); disk as the uncompressed pyramid, of which a ZSTD level keeps a fifth
to a half.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

from approxtree.errors import InvalidParameterError

#: Peak bytes per level-0 texel of each layer while baking (measured, rounded up): the
#: topographic shading on the DEM's own lattice (heights in memory, shade whole), the same
#: streamed strip by strip from a windowed raster, on a resampled lattice (h_T sampled at
#: every texel), Phong or Gouraud shading, a thematic raster resampled (its values and valid
#: mask whole, coloured and blended strip by strip: 9-10 bytes a texel measured on 4.7-19
#: million texels), a vector overlay, an image (warped strip by strip; its strips and the
#: blended copy are counted per layer).
BYTES_PER_TEXEL = {
    "topographic": 10,
    "streamed": 4,
    "resampled": 40,
    "phong": 100,
    "gouraud": 100,
    "thematic": 24,
    "overlay": 220,
    # An image is warped strip by strip: what it holds does not grow with the texture.
    "image": 1,
}
#: Each layer beyond the heaviest adds its blended copy.
EXTRA_LAYER_BYTES = 16
#: A level's side: GDAL addresses raster sizes as 32-bit signed ints.
MAX_SIDE = 2**31 - 1
#: The disk check refuses only a pyramid that could not fit even at this compression ratio
#: (ZSTD keeps 20-50 % of a shading; a mostly empty texture less): a full disk during the bake
#: is reported by the writer.
BEST_COMPRESSION = 10


def _size(n: float) -> str:
    """Bytes as text in the largest unit that keeps the figure under 1000 (up to PB)."""
    for unit in ("bytes", "kB", "MB", "GB", "TB"):
        if n < 1000:
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"


def check_bake_size(
    shape: tuple[int, int],
    texel: float,
    cell: float,
    layers: list[str],
    bands: int,
    max_texture_size: int,
    folder: str | os.PathLike,
    memory: int | None = None,
    free_disk: int | None = None,
) -> None:
    """InvalidParameterError when a texture of ``shape`` (rows, cols) level-0 texels of size
    ``texel`` (world units; ``cell`` the DEM's) cannot be baked here: a side past the format's
    limit, more memory than available (``BYTES_PER_TEXEL`` of ``layers``, keys of it), or a
    pyramid of ``bands`` bands that cannot fit the free disk at ``folder``. memory and
    free_disk: bytes (default: this machine's). The message gives the texel size that fits."""
    from approxtree.io._common import available_memory

    rows, cols = shape
    texels = rows * cols
    per_texel = max(BYTES_PER_TEXEL[k] for k in layers) + EXTRA_LAYER_BYTES * (len(layers) - 1)
    need = texels * per_texel
    have = available_memory() if memory is None else memory
    # Every level: each halves the one before until one fits the texture limit.
    level_texels, r, c = texels, rows, cols
    while max(r, c) > max_texture_size:
        r, c = -(-r // 2), -(-c // 2)
        level_texels += r * c
    raw = level_texels * bands
    target = Path(folder).absolute()
    where = next((p for p in (target, *target.parents) if p.exists()), Path("/"))
    free = shutil.disk_usage(where).free if free_disk is None else free_disk
    # Each limit passed, and the texel at which it would hold (texels scale as 1 / texel²).
    over: list[tuple[str, float]] = []
    if max(rows, cols) > MAX_SIDE:
        over.append(
            (f"a GeoTIFF level holds at most {MAX_SIDE} texels a side", max(rows, cols) / MAX_SIDE)
        )
    if need > have:
        over.append(
            (
                f"baking it holds about {_size(need)} in memory ({per_texel} bytes a texel for "
                f"{' + '.join(layers)}), and {_size(have)} is available",
                math.sqrt(need / have),
            )
        )
    if raw > free * BEST_COMPRESSION:
        over.append(
            (
                f"its pyramid is {_size(raw)} uncompressed, and {where} has {_size(free)} free",
                math.sqrt(raw / max(1, free * BEST_COMPRESSION)),
            )
        )
    if over:
        fits = texel * max(f for _, f in over)
        raise InvalidParameterError(
            f"A texel of {texel:g} makes a {cols} × {rows} texture ({texels:.3g} texels): "
            + "; ".join(w for w, _ in over)
            + f". Use a texel of at least {_round_up(fits)} (the DEM's cell is {cell:g})."
        )


def _round_up(x: float) -> str:
    """``x`` rounded up to two significant digits, as text."""
    if x <= 0 or not math.isfinite(x):
        return f"{x:g}"
    k = math.floor(math.log10(x)) - 1
    return f"{math.ceil(x / 10.0**k) * 10.0**k:.{max(0, -k)}f}"
