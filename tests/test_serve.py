"""``approxtree serve``: tiles made on request equal ``approxtree tiles``' files; HTTP semantics;
faults (damaged chunk, clients going away, malformed paths, SIGTERM).

The app is driven in-process by starlette's TestClient, or run by uvicorn on an ephemeral
port (a socket bound before the server starts, so a client's first request waits in the
backlog instead of polling); the SIGTERM test runs the command itself.
"""

from __future__ import annotations

import json
import os
import random
import selectors
import signal
import socket
import struct
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
from affine import Affine

from approxtree.datasets import fractal_heights
from approxtree.errors import StoreError
from approxtree.geometry import Grid
from approxtree.textures.bake import bake
from approxtree.tiles import write_3dtiles, write_quantized_mesh
from approxtree.tiles.serve import create_app
from approxtree.tiles.serve.cache import Busy, Entry, TileCache
from approxtree.tiles.serve.runner import bind
from approxtree.tiles.web_maps import write_web_map
from approxtree.tree import ApproximationTree, load_tree

REPO = Path(__file__).resolve().parents[1]

with warnings.catch_warnings():
    # starlette's TestClient warns that it prefers httpx2; httpx is what is installed.
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> dict:
    """A small store (129² fractal in degrees, ε 0.5), one imagery layer, and every output
    of ``approxtree tiles`` written from them with the defaults the server uses."""
    root = tmp_path_factory.mktemp("serve")
    heights = fractal_heights(129, seed=5, relief=200.0)
    grid = Grid(heights, Affine(0.0005, 0, -72.0, 0, -0.0005, 45.0), crs="EPSG:4326")
    tree = ApproximationTree.build(grid, epsilon=0.5, max_points=81, policy="grid", progress=False)
    store = root / "small.zarr"
    tree.save(store)
    layers = root / "layers"
    layers.mkdir()
    bake(grid, layers / "shading", gl=False)
    written = root / "written"
    written.mkdir()
    stored = load_tree(store, verify=False)
    write_3dtiles(stored, written / "3dtiles", textures=layers / "shading")
    terrain = stored.terrain
    write_quantized_mesh(terrain, written / "terrain", leaf_error=0.5)
    for kind in ("terrarium", "terrain-rgb"):
        write_web_map(kind, terrain, written / kind)
    write_web_map("imagery", terrain, written / "geographic", layers / "shading")
    write_web_map("imagery", terrain, written / "webmercator", layers / "shading", "webmercator")
    return {"root": root, "store": store, "layers": layers, "written": written}


@pytest.fixture(scope="module")
def client(site):
    with TestClient(create_app(str(site["store"]), str(site["layers"]))) as c:
        yield c


def files(folder: Path, pattern: str) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob(pattern)}


def test_served_tiles_equal_the_written_files(site, client):
    """tileset.json, every GLB, every quantized-mesh tile (gzip bytes as stored), every
    raster-dem and imagery tile (both tilings) are the bytes approxtree tiles wrote."""
    w = site["written"]
    r = client.get("/3dtiles/tileset.json")
    assert r.status_code == 200 and r.content == (w / "3dtiles" / "tileset.json").read_bytes()
    glbs = files(w / "3dtiles", "*.glb")
    assert len(glbs) > 20
    for rel, data in glbs.items():
        assert client.get(f"/3dtiles/{rel}").content == data, rel
    layer = json.loads(client.get("/terrain/layer.json").content)
    assert layer["available"] == json.loads((w / "terrain" / "layer.json").read_text())["available"]
    for rel, data in files(w / "terrain", "*.terrain").items():
        # The bytes on the wire (gzip-encoded, as CesiumJS takes them) against the file.
        with client.stream("GET", f"/terrain/{rel}", headers={"accept-encoding": "gzip"}) as r:
            assert r.headers["content-encoding"] == "gzip"
            assert b"".join(r.iter_raw()) == data, rel
    for prefix, folder in [
        ("/terrarium", "terrarium"),
        ("/terrain-rgb", "terrain-rgb"),
        ("/imagery/shading", "geographic"),
        ("/imagery/shading/webmercator", "webmercator"),
    ]:
        tiles = files(w / folder, "*.png")
        assert tiles
        for rel, data in tiles.items():
            assert client.get(f"{prefix}/{rel}").content == data, (prefix, rel)


def test_gzip_etag_and_caching_headers(client):
    """JSON and GLB go gzip to a client that takes it and identity to one that refuses it,
    with Vary; the ETag of either gives 304; Cache-Control and CORS are on every response."""
    gz = client.get("/3dtiles/0/0.glb", headers={"accept-encoding": "gzip, br"})
    plain = client.get("/3dtiles/0/0.glb", headers={"accept-encoding": "identity"})
    assert gz.headers["content-encoding"] == "gzip" and "content-encoding" not in plain.headers
    assert gz.content == plain.content and gz.headers["vary"] == "Accept-Encoding"
    assert gz.headers["etag"] != plain.headers["etag"]
    assert (
        client.get("/3dtiles/0/0.glb", headers={"accept-encoding": "gzip;q=0"}).headers.get(
            "content-encoding"
        )
        is None
    )
    for tag in (gz.headers["etag"], plain.headers["etag"], "W/" + plain.headers["etag"], "*"):
        again = client.get("/3dtiles/0/0.glb", headers={"if-none-match": tag})
        assert again.status_code == 304 and again.content == b""
        assert again.headers["etag"] and again.headers["cache-control"]
    assert client.get("/3dtiles/0/0.glb", headers={"if-none-match": '"other"'}).status_code == 200
    png = client.get("/terrarium/0/0/0.png")
    assert png.headers["content-type"] == "image/png" and "content-encoding" not in png.headers
    assert png.headers["cache-control"] == "public, max-age=3600"
    assert client.get("/terrain/layer.json").headers["cache-control"] == "no-cache"
    assert png.headers["access-control-allow-origin"] == "*"
    pre = client.options(
        "/terrain/layer.json",
        headers={"origin": "http://x", "access-control-request-method": "GET",
                 "access-control-request-headers": "if-none-match"},
    )  # fmt: skip
    assert pre.status_code == 204 and pre.headers["access-control-allow-origin"] == "*"
    assert "GET" in pre.headers["access-control-allow-methods"]
    head = client.head("/terrarium/0/0/0.png")
    assert head.status_code == 200 and head.content == b""


def test_tilejson_documents_and_viewer(client, site):
    """The TileJSONs name absolute tile URLs the server answers; / redirects to the viewer
    page with the terrain and the first imagery layer; /health reports the cache."""
    doc = client.get("/terrarium/tilejson.json").json()
    assert doc["tiles"][0].endswith("/terrarium/{z}/{x}/{y}.png")
    assert doc["approxtree"]["encoding"] == "terrarium"
    geo = client.get("/imagery/shading/tilejson.json").json()
    assert geo["scheme"] == "tms" and geo["approxtree"]["tiling"] == "geographic"
    r = client.get("/", follow_redirects=False)
    assert r.status_code == 307
    assert "terrain=/terrain/" in r.headers["location"]
    assert "imagery=/imagery/shading/tilejson.json" in r.headers["location"]
    assert client.get(r.headers["location"]).status_code == 200
    health = client.get("/health").json()
    assert health["status"] == "ok" and health["layers"] == ["shading"]
    assert 0 < health["cache"]["bytes"] <= health["cache"]["limit"]


def test_errors_are_json_with_a_message(client):
    """Unknown layers, tiles outside the sets, unknown nodes and extensions are 404 with a
    message saying what exists; no response carries a traceback."""
    cases = {
        "/imagery/nope/0/0/0.png": "layers: shading",
        "/terrain/0/7/0.terrain": "layer.json",
        "/3dtiles/0/99999.glb": "no tile",
        "/terrarium/0/0/0.jpg": ".jpg",
        "/terrarium/30/0/0.png": "tilejson",
        "/nowhere": "Not Found",
    }
    for path, words in cases.items():
        r = client.get(path)
        assert r.status_code == 404, path
        assert words in r.json()["error"], (path, r.text)
        assert "Traceback" not in r.text


#: Paths the generator below can stumble on that are not malformed.
VALID = {"/3dtiles/tileset.json", "/terrain/layer.json"}


def malformed_paths(count: int, seed: int = 0) -> list[str]:
    """``count`` paths no client should send: bad numbers, huge numbers, traversal, unknown
    extensions and layers, stray encodings, very long segments."""
    rng = random.Random(seed)
    words = ["3dtiles", "terrain", "imagery", "terrarium", "terrain-rgb", "health", "viewer", ""]
    junk = ["..", "%2e%2e", "-1", "1e9", "0x10", "99999999999999999999", "%00", "a b", "☃",
            "NaN", "tileset.json", "layer.json", "x" * 300, "%ff%fe", "0.5", "/",
            "shading"]  # fmt: skip
    exts = [".png", ".terrain", ".glb", ".jpg", ".json", ".exe", "", ".png.png", ".PNG"]
    out = []
    while len(out) < count:
        parts = [rng.choice(words)] + [rng.choice(junk) for _ in range(rng.randint(1, 5))]
        path = "/" + "/".join(parts) + rng.choice(exts)
        if rng.random() < 0.2:
            path = path.replace("/", "//", 1)
        if path not in VALID:
            out.append(path)
    return out


def raw_statuses(port: int, paths: list[str]) -> list[int]:
    """The status of a GET of each path, sent as it is (no client library normalising it) on
    keep-alive connections, a new one after each the server closes."""
    out = []
    conn = reader = None
    for path in paths:
        if conn is None:
            conn = socket.create_connection(("127.0.0.1", port), timeout=60)
            reader = conn.makefile("rb")
        conn.sendall(b"GET " + path.encode() + b" HTTP/1.1\r\nHost: t\r\n\r\n")
        status = int(reader.readline().split()[1])
        length, close = 0, False
        while (line := reader.readline()) not in (b"\r\n", b""):
            name, _, value = line.decode("latin-1").partition(":")
            if name.lower() == "content-length":
                length = int(value)
            close |= name.lower() == "connection" and "close" in value.lower()
        reader.read(length)
        out.append(status)
        if close:
            reader.close()
            conn.close()
            conn = None
    if conn is not None:
        reader.close()
        conn.close()
    return out


def test_a_thousand_malformed_paths_are_all_4xx(site):
    """1,000 malformed paths sent raw to the running server: every answer is a 4xx (never
    200, never 5xx), and the server still serves afterwards."""
    paths = malformed_paths(1000)
    with LiveServer(create_app(str(site["store"]), str(site["layers"]))) as live:
        statuses = raw_statuses(live.port, paths)
        assert live.get("/health")[0] == 200
    bad = [(p, s) for p, s in zip(paths, statuses, strict=True) if not 400 <= s < 500]
    assert len(statuses) == 1000 and not bad, bad[:5]


def test_damaged_chunk_is_a_500_with_the_store_error_and_the_server_stays_up(site, tmp_path):
    """A flipped byte in the patches' chunk: the GLB request gets 500 with the StoreError's
    message (the one load_tree's read gives); other tiles and /health still answer."""
    import shutil

    store = tmp_path / "damaged.zarr"
    shutil.copytree(site["store"], store)
    chunk = store / "patches" / "grid" / "z_data" / "c" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    with pytest.raises(StoreError) as expected:
        load_tree(store, verify=False).read_patch(0)
    with TestClient(create_app(str(store))) as c:
        r = c.get("/3dtiles/0/0.glb")
        assert r.status_code == 500
        assert r.json()["error"] == str(expected.value)
        assert c.get("/3dtiles/0/0.glb").status_code == 500
        assert c.get("/health").status_code == 200
        assert c.get("/terrain/layer.json").status_code == 200
        assert c.get("/terrarium/0/0/0.png").status_code == 200


class LiveServer:
    """The app under uvicorn on 127.0.0.1 in a thread (port 0), for raw-socket clients."""

    def __init__(self, app) -> None:
        import uvicorn

        self.sock = bind("127.0.0.1", 0)
        self.port = self.sock.getsockname()[1]
        config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]})

    def __enter__(self) -> LiveServer:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=60)
        self.sock.close()
        assert not self.thread.is_alive()

    def get(self, path: str) -> tuple[int, bytes]:
        """A whole GET on a new connection: (status, body)."""
        import httpx

        r = httpx.get(f"http://127.0.0.1:{self.port}{path}", timeout=60)
        return r.status_code, r.content


def test_clients_going_away_mid_response_leave_the_server_serving(site):
    """Clients that close after a few bytes of a large response, or before a tile is made:
    the server keeps serving, and the tile left unfinished is made and served whole."""
    with LiveServer(create_app(str(site["store"]), str(site["layers"]))) as live:
        for path in ["/3dtiles/tileset.json", "/3dtiles/0/0.glb", "/terrain/0/0/0.terrain"] * 3:
            with socket.create_connection(("127.0.0.1", live.port), timeout=60) as s:
                s.sendall(f"GET {path} HTTP/1.1\r\nHost: t\r\n\r\n".encode())
                assert s.recv(64).startswith(b"HTTP/1.1")
                # Linger 0: the close is a reset, the rest of the response has nowhere to go.
                s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        # Gone before the tile is made (the request sent, the socket closed at once).
        for z, x, y in [(5, 18, 12), (6, 36, 25)]:
            with socket.create_connection(("127.0.0.1", live.port), timeout=60) as s:
                s.sendall(f"GET /terrarium/{z}/{x}/{y}.png HTTP/1.1\r\nHost: t\r\n\r\n".encode())
        status, body = live.get("/health")
        assert status == 200 and json.loads(body)["status"] == "ok"
        written = site["written"]
        assert (
            live.get("/3dtiles/tileset.json")[1] == (written / "3dtiles/tileset.json").read_bytes()
        )
        for rel, data in files(written / "terrarium", "*.png").items():
            assert live.get(f"/terrarium/{rel}") == (200, data)


def test_sigterm_stops_the_command_cleanly(site):
    """approxtree serve --port 0 prints its URL, serves, and on SIGTERM finishes and exits
    (by the signal, as uvicorn re-raises it) without a traceback."""
    import httpx

    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "approxtree", "serve", str(site["store"]), "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        assert sel.select(timeout=120), "no URL printed within 120 s"
        line = proc.stdout.readline().decode()
        url = line.split(" at ")[1].split()[0]
        assert url.startswith("http://127.0.0.1:")
        assert httpx.get(url + "health", timeout=60).json()["status"] == "ok"
        assert httpx.get(url + "terrarium/0/0/0.png", timeout=60).status_code == 200
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read().decode()
    assert code in (0, -signal.SIGTERM), err
    assert "Traceback" not in err and "Error" not in err


def test_cache_is_bounded_and_refuses_past_max_pending():
    """Entries beyond the byte bound evict the least recently used; an entry larger than the
    bound is not kept; with max_pending tiles being made, another request gets Busy at once,
    while requests for the tile being made wait for that one making."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(2) as pool:
        cache = TileCache(10_000, pool, max_pending=1)
        for i in range(20):
            cache.put(i, Entry("image/png", bytes(1000)))
        stats = cache.stats()
        assert stats["bytes"] <= 10_000 and cache.get(19) is not None and cache.get(0) is None
        cache.put("big", Entry("image/png", bytes(20_000)))
        assert cache.get("big") is None
        started, release = threading.Event(), threading.Event()
        calls = []

        def slow() -> Entry:
            calls.append(1)
            started.set()
            release.wait(timeout=60)
            return Entry("image/png", b"x")

        async def scenario():
            first = asyncio.ensure_future(cache.get_or_make("slow", slow))
            same = asyncio.ensure_future(cache.get_or_make("slow", slow))
            # Bounded wait until the making runs (both requests are then waiting on it).
            assert await asyncio.to_thread(started.wait, 60)
            with pytest.raises(Busy):
                await cache.get_or_make("other", slow)
            release.set()
            return await first, await same

        a, b = asyncio.run(scenario())
        assert a is b and len(calls) == 1


def test_serve_command_refuses_what_is_not_a_store(tmp_path):
    """serve on a file that is no tree store: exit 2 and one Error line saying what to give."""
    from click.testing import CliRunner

    from approxtree.cli import main

    (tmp_path / "dem.npy").write_bytes(np.zeros(4).tobytes())
    result = CliRunner().invoke(main, ["serve", str(tmp_path / "dem.npy")])
    assert result.exit_code == 2 and "not a tree store" in result.output
