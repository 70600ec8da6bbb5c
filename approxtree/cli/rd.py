"""``approxtree rd``: Rate–distortion comparison: binary-tree decimation and refinement, uniform
grid, TIN and RTIN at the same triangle counts (L2, max error, SNR in dB, seconds).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from approxtree.cli.common import _reports_errors, _terrain_of
from approxtree.cli.options import (
    json_option,
    overwrite_option,
    quiet_option,
    reader_options,
    replaceable,
)


def _rates(ctx: click.Context, param: click.Parameter, value: str) -> list[int]:
    """Parse "512,1024" into triangle counts."""
    try:
        rates = [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        rates = []
    if not rates or min(rates) < 2:
        raise click.BadParameter(f"expected triangle counts >= 2 like 512,1024, got {value!r}")
    return rates


@click.command()
@click.argument("dem", type=click.Path())
@click.option(
    "--rates",
    callback=_rates,
    default="512,1024,2048,4096",
    show_default=True,
    help="Triangle counts at which every method is measured.",
)
@click.option(
    "--size",
    type=int,
    default=None,
    help="Side 2^k + 1 of the centred window used [default: the largest that fits].",
)
@click.option(
    "--methods",
    default="decimation,refinement,uniform,tin,rtin",
    show_default=True,
    help="Methods to compare (comma-separated).",
)
@click.option("--plot", type=click.Path(dir_okay=False), help="PNG of the L2 and L∞ curves.")
@reader_options
@overwrite_option
@quiet_option
@json_option
@_reports_errors
def rd(
    dem: str,
    rates: list[int],
    size: int | None,
    methods: str,
    plot: str | None,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    quiet: bool,
    as_json: bool,
) -> None:
    """Rate–distortion comparison: binary-tree decimation and refinement, uniform grid, TIN
    and RTIN at the same triangle counts (L2, max error, SNR in dB, seconds)."""
    from approxtree.geometry import Grid
    from approxtree.progress import progress_bar
    from approxtree.rd import lattice_heights, rd_curves
    from approxtree.rd.curves import json_ready, plot_rd

    if plot:
        from approxtree.io.output_path import check_output_file

        check_output_file(plot, "plot")
        replaceable(plot, "image")
    terrain = _terrain_of(dem, encoding, nodata_policy, ground_only, height_scale)
    if not isinstance(terrain, Grid):
        from approxtree.errors import InvalidParameterError

        raise InvalidParameterError(
            f"The rd command needs a raster grid, {dem} reads as a {terrain.kind}."
        )
    heights = lattice_heights(terrain, size)
    names = [m.strip() for m in methods.split(",") if m.strip()]
    with progress_bar("rate-distortion", unit="stage", quiet=quiet) as on_progress:
        result = rd_curves(heights, rates, names, progress=on_progress)
    if plot:
        plot_rd(result, plot, title=f"{Path(dem).name} ({heights.shape[0]}²)")
    figures = json_ready(result)
    figures["dem"] = str(dem)
    if as_json:
        click.echo(json.dumps(figures))
        return
    click.echo(f"{Path(dem).name}: {heights.shape[0]}² grid, SNR (dB) / max error")
    click.echo("method       " + "".join(f"{r:>16}" for r in figures["rates"]) + "   seconds")
    for name, data in figures["methods"].items():
        cells = "".join(
            f"{(row['snr_db'] or float('inf')):>8.2f} /{row['max_error']:>6.1f}"
            for row in data["rows"]
        )
        click.echo(f"{name:<13}{cells}   {data['seconds']}")
