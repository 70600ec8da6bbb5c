"""``approxtree serve``: serve a tree store's web tiles over HTTP, each made on request."""

from __future__ import annotations

import os

import click

from approxtree.cli.common import _reports_errors


@click.command()
@click.argument("store", type=click.Path(), required=False)
@click.option(
    "--archive",
    "archives",
    type=click.Path(dir_okay=False, exists=True),
    multiple=True,
    help="A PMTiles archive (approxtree tiles --out X.pmtiles) whose imagery or raster-dem "
    "tiles are served as stored, at the URLs of the same tiles made from a store: "
    "/terrarium/, /terrain-rgb/, /imagery/NAME/webmercator/. Repeatable.",
)
@click.option(
    "--textures",
    type=click.Path(file_okay=False),
    default=None,
    help="A texture pyramid (approxtree bake) or a folder of them: the imagery layers, named "
    "by their folders; 3D Tiles embed the first one's texture.",
)
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on.")
@click.option("--port", type=int, default=8000, show_default=True, help="Port (0: any free one).")
@click.option(
    "--cache-mb",
    type=click.IntRange(min=1),
    default=256,
    show_default=True,
    help="Bound of the cache of made tiles, MiB.",
)
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    default=None,
    help="Threads making tiles [default: the CPU count, at most 8].",
)
@click.option(
    "--max-pending",
    type=click.IntRange(min=1),
    default=256,
    show_default=True,
    help="Tiles made or queued at once; further requests get 503 (Retry-After).",
)
@_reports_errors
def serve(
    store: str | None,
    archives: tuple[str, ...],
    textures: str | None,
    host: str,
    port: int,
    cache_mb: int,
    threads: int | None,
    max_pending: int,
) -> None:
    """Serve the web tiles of STORE (a tree store from `approxtree build`) at
    http://HOST:PORT/, made on request and identical to `approxtree tiles`' files:
    /3dtiles/tileset.json, /terrain/layer.json (quantized-mesh), /imagery/LAYER/tilejson.json,
    /terrarium/ and /terrain-rgb/ (MapLibre raster-dem), /health, and the viewer page at /.
    STORE may instead be a PMTiles archive (as --archive; then no store is needed).
    Runs until Ctrl-C or SIGTERM, then finishes the requests under way."""
    from approxtree.cli.common import _is_tree
    from approxtree.errors import StoreError
    from approxtree.tiles.serve import serve as run

    given = list(archives)
    if store is not None and store.lower().endswith(".pmtiles"):
        given.insert(0, store)
        store = None
    if store is None and not given:
        raise StoreError(
            "Nothing to serve: give a tree store (approxtree build TERRAIN --out NAME.zarr) "
            "or PMTiles archives (--archive X.pmtiles)."
        )
    if store is not None and not _is_tree(store):
        raise StoreError(
            f"{store} is not a tree store: serve reads one (approxtree build TERRAIN --out "
            "NAME.zarr makes it)."
        )

    def ready(url: str) -> None:
        what = ", ".join(([store] if store else []) + given)
        click.echo(f"Serving {what} at {url} (open it for the viewer; Ctrl-C or SIGTERM stops)")

    workers = threads or max(1, min(os.cpu_count() or 1, 8))
    run(
        store,
        textures,
        host,
        port,
        cache_mb << 20,
        workers,
        max_pending,
        on_ready=ready,
        archives=given,
    )
