"""``approxtree verify``: Check an output of approxtree (tree store, mesh file, 3D Tiles,
quantized-mesh or texture pyramid folder) against its source terrain, recomputing every claim
independently of the code that wrote it; exit 0 when every claim holds, 1 when one does not.
"""

from __future__ import annotations

import json
import math
import sys
from typing import Any

import click

from approxtree.cli import common
from approxtree.cli.common import _reports_errors
from approxtree.cli.options import json_option, reader_options, textures_option
from approxtree.io.warp import RESAMPLINGS


def _shown(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    return str(value)


def _print(report) -> None:
    """The report as text: one line per check, the figures, the worst offenders."""
    click.echo(f"{report.kind} {report.output}: {'every claim holds' if report.ok else 'FAILED'}")
    width = max((len(name) for name in report.checks), default=0)
    for check in report.checks.values():
        mark = "ok  " if check.ok else "FAIL"
        tally = f"{check.items} checked" + (f", {check.failures} failed" if check.failures else "")
        click.echo(f"  {mark} {check.name:<{width}}  {check.description} ({tally})")
    for key, value in report.figures.items():
        click.echo(f"  {key}: {_shown(value)}")
    for line in report.not_checked:
        click.echo(f"  not checked: {line}")
    offenders = report.offenders
    if offenders:
        click.echo("worst offenders (check, address, claimed, measured):")
        for o in offenders[:10]:
            click.echo(f"  {o.check}  {o.address}  {_shown(o.claimed)}  {_shown(o.measured)}")


@click.command()
@click.argument("output", type=click.Path())
@click.option(
    "--source",
    type=click.Path(dir_okay=False),
    help="The terrain file the output was made from (read with the reader options below); "
    "without it only completeness, checksums and structure are checked.",
)
@click.option(
    "--max-error",
    type=float,
    default=None,
    help="Mesh files: the max error claimed, for a file that records none.",
)
@click.option(
    "--hillshade",
    is_flag=True,
    help="Texture pyramids: the bake is a plain hillshade at gdaldem's defaults; level 0 is "
    "compared with `gdaldem hillshade` of the source.",
)
@textures_option(
    "Imagery tiles: the texture pyramid they were cut from (then --textures DETAIL@ZOOM when "
    "a detail pyramid was laid over); every pixel is compared with it resampled at the "
    "pixel's centre."
)
@click.option(
    "--image",
    type=click.Path(exists=True, dir_okay=False),
    help="Texture pyramids: the image of a `bake --shading none --image FILE`; every level "
    "is compared with its box-filtered reprojection (within 1 per channel).",
)
@click.option(
    "--resampling",
    type=click.Choice(list(RESAMPLINGS)),
    default="bilinear",
    show_default=True,
    help="The --resampling the image was baked with.",
)
@reader_options
@json_option
@_reports_errors
def verify(
    output: str,
    source: str | None,
    max_error: float | None,
    hillshade: bool,
    textures: list,
    image: str | None,
    resampling: str,
    encoding,
    nodata_policy,
    ground_only,
    height_scale,
    as_json: bool,
) -> None:
    """Check an output of approxtree (tree store, mesh file, 3D Tiles, quantized-mesh or texture
    pyramid folder) against its source terrain, recomputing every claim independently of the
    code that wrote it; exit 0 when every claim holds, 1 listing the worst offenders."""
    from approxtree.verify import verify as run_verify

    terrain = None
    if source is not None:
        terrain = common._open(source, encoding, nodata_policy, ground_only, height_scale)
    report = run_verify(
        output,
        terrain,
        max_error=max_error,
        hillshade=hillshade,
        source_file=source,
        textures=textures[0] if textures else None,
        image=image,
        resampling=resampling,
    )
    if as_json:
        click.echo(json.dumps(report.to_dict()))
    else:
        _print(report)
    sys.exit(0 if report.ok else 1)
