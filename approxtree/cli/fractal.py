"""``approxtree fractal``: Write a seeded fractal DEM of any size as a tiled, compressed GeoTIFF,
block by block (memory stays at a few blocks).
"""

from __future__ import annotations

import time

import click

from approxtree.cli.common import _emit, _reports_errors
from approxtree.cli.options import json_option, overwrite_option, quiet_option, replaceable


@click.command()
@click.argument("out", type=click.Path(dir_okay=False))
@click.option("--size", type=int, required=True, help="Rows (and columns, unless --cols).")
@click.option("--cols", type=int, default=None, help="Columns [default: --size].")
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed.")
@click.option(
    "--cell-size", type=float, default=1.0, show_default=True, help="Cell edge (map units)."
)
@click.option("--crs", default=None, help="CRS written in the file (EPSG:NNNN, WKT, PROJ).")
@click.option(
    "--hurst",
    type=float,
    default=0.9,
    show_default=True,
    help="Roughness: octave amplitude ∝ wavelength^hurst.",
)
@click.option(
    "--relief",
    type=float,
    default=500.0,
    show_default=True,
    help="Amplitude of the longest octave (z units); heights lie around relief ± relief.",
)
@click.option(
    "--wavelength",
    type=float,
    default=8192.0,
    show_default=True,
    help="Longest octave's wavelength (cells).",
)
@click.option(
    "--holes", type=float, default=0.0, show_default=True, help="Fraction of nodata cells."
)
@click.option(
    "--compress",
    type=click.Choice(["deflate", "zstd", "lzw", "none"]),
    default="deflate",
    show_default=True,
    help="Tile compression (with the floating-point predictor).",
)
@click.option("--cog", is_flag=True, help="Cloud Optimized GeoTIFF with overviews.")
@click.option("--workers", type=int, default=None, help="Threads [default: the core count].")
@click.option(
    "--block",
    type=int,
    default=2048,
    show_default=True,
    help="Cells per computed block edge (a multiple of 512).",
)
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def fractal(
    out: str,
    size: int,
    cols: int | None,
    seed: int,
    cell_size: float,
    crs: str | None,
    hurst: float,
    relief: float,
    wavelength: float,
    holes: float,
    compress: str,
    cog: bool,
    workers: int | None,
    block: int,
    quiet: bool,
    as_json: bool,
) -> None:
    """Write a seeded fractal DEM of any size as a tiled, compressed GeoTIFF, block by block
    (memory stays at a few blocks). Heights depend on (row, col, seed) only: a smaller DEM of
    the same seed is a crop of a larger one. The bytes it will take are checked against the
    disk's free space before the first block (and shown on the progress bar; -q: no bar)."""
    from approxtree.datasets import write_fractal_terrain
    from approxtree.io.output_path import check_output_file

    check_output_file(out, "GeoTIFF")
    replaceable(out, "GeoTIFF")
    t0 = time.perf_counter()
    path = write_fractal_terrain(
        out,
        size,
        cols,
        seed=seed,
        hurst=hurst,
        relief=relief,
        wavelength=wavelength,
        holes=holes,
        cell_size=cell_size,
        crs=crs,
        compress=compress,
        cog=cog,
        workers=workers,
        block=block,
        progress=not (as_json or quiet),
    )
    seconds = time.perf_counter() - t0
    rows, ncols = size, size if cols is None else cols
    nbytes = path.stat().st_size
    figures = {
        "path": str(path),
        "rows": rows,
        "cols": ncols,
        "seed": seed,
        "seconds": round(seconds, 3),
        "bytes": nbytes,
        "float32_bytes": rows * ncols * 4,
        "compression_ratio": round(rows * ncols * 4 / nbytes, 3),
    }
    _emit(figures, as_json)
