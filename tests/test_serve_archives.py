"""``approxtree serve`` from PMTiles archives: their imagery and raster-dem tiles answered as
stored, at the URLs of the same tiles made from a store, with the same HTTP semantics.

The app is driven in-process by starlette's TestClient (httpx over the ASGI app), as in
test_serve.py; the archives are read back independently with the ``pmtiles`` package.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
from affine import Affine
from pmtiles.reader import MmapSource, all_tiles

from approxtree.datasets import fractal_heights
from approxtree.errors import StoreError
from approxtree.geometry import Grid
from approxtree.textures.bake import bake
from approxtree.tiles.serve import create_app
from approxtree.tiles.web_maps import write_web_map
from approxtree.tree import ApproximationTree

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> dict:
    """A small store (129² fractal in degrees), a shading pyramid, and two archives: Terrarium
    in 256 px tiles (the store's own are 512 px) and the shading as Web Mercator imagery."""
    root = tmp_path_factory.mktemp("archives")
    heights = fractal_heights(129, seed=5, relief=200.0)
    grid = Grid(heights, Affine(0.0005, 0, -72.0, 0, -0.0005, 45.0), crs="EPSG:4326")
    tree = ApproximationTree.build(grid, epsilon=0.5, max_points=81, policy="grid", progress=False)
    store = root / "small.zarr"
    tree.save(store)
    bake(grid, root / "shading", gl=False)
    terrarium = root / "dem.pmtiles"
    write_web_map("terrarium", grid, terrarium, tile_size=256)
    imagery = root / "shade.pmtiles"
    write_web_map("imagery", grid, imagery, root / "shading", "webmercator")
    return {"store": store, "terrarium": terrarium, "imagery": imagery}


def stored(path: Path) -> dict[tuple[int, int, int], bytes]:
    """(z, x, y) → bytes of every tile of an archive, read by the pmtiles package."""
    with open(path, "rb") as f:
        return {zxy: bytes(data) for zxy, data in all_tiles(MmapSource(f))}


def test_archive_tiles_are_served_as_stored_without_a_store(site):
    """Archives only: every tile of both archives at its URL is the archive's bytes, with
    ETag/304, Cache-Control and CORS; the store's kinds answer 404 saying why."""
    archives = [str(site["terrarium"]), str(site["imagery"])]
    with TestClient(create_app(None, archives=archives)) as client:
        for prefix, path in (
            ("/terrarium", site["terrarium"]),
            ("/imagery/shade/webmercator", site["imagery"]),
        ):
            tiles = stored(path)
            assert tiles
            for (z, x, y), data in tiles.items():
                r = client.get(f"{prefix}/{z}/{x}/{y}.png")
                assert r.status_code == 200 and r.content == data, (prefix, z, x, y)
                assert r.headers["content-type"] == "image/png"
        r = client.get("/terrarium/0/0/0.png")
        assert r.headers["cache-control"] == "public, max-age=3600"
        assert r.headers["access-control-allow-origin"] == "*"
        again = client.get("/terrarium/0/0/0.png", headers={"if-none-match": r.headers["etag"]})
        assert again.status_code == 304 and again.content == b""
        for url in ("/3dtiles/tileset.json", "/terrain/layer.json", "/terrain-rgb/0/0/0.png"):
            r = client.get(url)
            assert r.status_code == 404 and "archives only" in r.json()["error"], url


def test_archive_tilejson_health_and_missing_tiles(site):
    """The TileJSON is the archive's metadata with an absolute URL template the server
    answers; /health lists the archives; absent tiles and other formats are 404s."""
    archives = [str(site["terrarium"]), str(site["imagery"])]
    with TestClient(create_app(None, archives=archives)) as client:
        doc = client.get("/terrarium/tilejson.json").json()
        assert doc["tiles"][0].endswith("/terrarium/{z}/{x}/{y}.png")
        assert doc["approxtree"]["encoding"] == "terrarium"
        assert doc["approxtree"]["tile_size"] == 256
        z, x, y = next(iter(stored(site["terrarium"])))
        url = doc["tiles"][0].replace("http://testserver", "").format(z=z, x=x, y=y)
        assert client.get(url).status_code == 200
        assert client.get("/imagery/shade/webmercator/tilejson.json").json()["tiles"]
        assert client.get("/health").json()["archives"] == {
            "dem.pmtiles": "/terrarium/",
            "shade.pmtiles": "/imagery/shade/webmercator/",
        }
        for url in ("/terrarium/0/0/0.webp", "/terrarium/3/0/0.png", "/terrarium/40/0/0.png"):
            r = client.get(url)
            assert r.status_code == 404 and r.json()["error"], url


def test_an_archive_wins_over_the_same_tiles_made_from_the_store(site):
    """With a store and a Terrarium archive, /terrarium/ gives the archive's 256 px tiles,
    and the store still makes what the archive does not cover (terrain-rgb, 3D Tiles)."""
    app = create_app(str(site["store"]), archives=[str(site["terrarium"])])
    with TestClient(app) as client:
        r = client.get("/terrarium/0/0/0.png")
        assert r.content == stored(site["terrarium"])[(0, 0, 0)]
        assert client.get("/terrain-rgb/0/0/0.png").status_code == 200
        assert client.get("/3dtiles/tileset.json").status_code == 200


def test_archives_that_cannot_be_served_are_refused(site, tmp_path):
    """Not a PMTiles file, or two archives at the same URLs: StoreError naming the file;
    the command takes an archive in place of a store."""
    from click.testing import CliRunner

    from approxtree.cli import main

    bad = tmp_path / "bad.pmtiles"
    bad.write_bytes(b"not an archive at all" * 10)
    with pytest.raises(StoreError, match=r"bad\.pmtiles"):
        create_app(None, archives=[str(bad)])
    twin = tmp_path / "other.pmtiles"
    twin.write_bytes(site["terrarium"].read_bytes())
    with pytest.raises(StoreError, match="both be served at /terrarium/"):
        create_app(None, archives=[str(site["terrarium"]), str(twin)])
    with pytest.raises(StoreError, match="Nothing to serve"):
        create_app(None)
    result = CliRunner().invoke(main, ["serve", str(bad)])
    assert result.exit_code == 2 and "bad.pmtiles" in result.output
