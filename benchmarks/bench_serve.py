"""``approxtree serve`` under load on loopback: a CesiumJS-like access pattern, warm and cold.

The NC DEM of ../shared/data is built into a tree store and baked into two imagery layers
(shading, thematic over shading) unless ``--store``/``--textures`` are given; the server runs
as ``approxtree serve`` in its own process (``--server-cpus``: pinned with taskset) on
127.0.0.1, port 0.

The pattern (seeded, ``--requests`` in all, ``--clients`` at once, each client one keep-alive
connection asking its sessions' requests one after the other), from the server's own
documents (layer.json, tileset.json, the TileJSONs), in sessions of three kinds:

- CesiumJS globe (half the sessions): layer.json, then level by level from 0 down to a random
  depth near the deepest, the available terrain tiles of the 3 × 3 block around a random point
  of the terrain, each with the imagery tile of the same address (one layer, the drape);
- MapLibre (a quarter): the Terrarium TileJSON, then zoom by zoom the 3 × 3 block of
  Terrarium and Web Mercator imagery tiles around a random point;
- 3D Tiles (a quarter): tileset.json, then depth by depth the tiles whose region holds a
  random point.

Runs: ``cold`` (a fresh server: the pattern as it comes, tiles made on first request),
``cold_distinct`` (another fresh server: every distinct URL of the pattern once, so every
request makes a tile: the server's making rate) and ``warm`` (the pattern again on the first
server, every tile made). Each reports requests, errors (any status but 200), wall seconds,
tiles/s, p50/p99 latency; the server's RSS is taken after start-up and after each run
(psutil, the server process).

The load generator speaks HTTP/1.1 over asyncio streams itself: httpx's async client cost
~10 ms of CPU per request here (it topped out near 120 requests/s against a server that
answers 1,100/s), so it would have measured itself. Bounded in time: every request has a
timeout and each run a deadline.

    python benchmarks/bench_serve.py [--requests 10000] [--clients 64] [--cache-mb 256]
        [--server-cpus 0,1] [--store S --textures D] [--data-dir DIR]

Results: benchmarks/results/serve.json and serve.png (latency distributions, throughput
against the targets: warm >= 2000 tiles/s with p99 <= 50 ms, cold >= 200 tiles/s, RSS within
the cache bound + 200 MB).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import platform
import random
import re
import selectors
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import urlsplit

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
REPO = Path(__file__).resolve().parents[1]
#: Seconds a request may take, and a whole run.
REQUEST_TIMEOUT = 60.0
RUN_DEADLINE = 900.0
TARGETS = {"warm_tiles_per_s": 2000, "warm_p99_ms": 50, "cold_tiles_per_s": 200, "rss_mb": 200}


def cli(*args: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    subprocess.run([sys.executable, "-m", "approxtree", *args], check=True, env=env)


def prepare(data_dir: Path, tmp: Path) -> tuple[str, str]:
    """The NC tree store and a folder of two texture pyramids (shading, thematic)."""
    dem = data_dir / "nc" / "elev_ned_30m.tif"
    store = tmp / "nc.zarr"
    layers = tmp / "layers"
    cli("build", str(dem), "--out", str(store), "--json")
    layers.mkdir()
    cli("bake", str(store), "--out", str(layers / "shading"), "--no-gl", "--quiet", "--json")
    landuse = data_dir / "nc" / "landuse_r.tif"
    cli(
        "bake", str(dem), "--thematic", str(landuse), "--palette", "landclass96",
        "--out", str(layers / "thematic"), "--no-gl", "--quiet", "--json",
    )  # fmt: skip
    return str(store), str(layers)


class Server:
    """``approxtree serve`` in a child process; ``url`` once it listens."""

    def __init__(self, store: str, textures: str, cache_mb: int, cpus: str | None) -> None:
        cmd = [sys.executable, "-m", "approxtree", "serve", store, "--textures", textures]
        cmd += ["--port", "0", "--cache-mb", str(cache_mb)]
        if cpus and shutil.which("taskset"):
            cmd = ["taskset", "-c", cpus, *cmd]
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        }
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout=120):
            self.stop()
            raise RuntimeError("the server did not start within 120 s")
        line = self.proc.stdout.readline().decode()
        match = re.search(r"http://[^ ]+/", line)
        if not match:
            self.stop()
            raise RuntimeError(
                f"the server did not start: {line} {self.proc.stderr.read()[-2000:]}"
            )
        self.url = match.group(0)

    def rss_mb(self) -> float:
        import psutil

        proc = psutil.Process(self.proc.pid)
        # taskset execs the server: the same process.
        return proc.memory_info().rss / 2**20

    def stop(self) -> int:
        self.proc.terminate()
        try:
            return self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


# -- the load generator ------------------------------------------------------------------------


async def _get(reader, writer, path: str) -> tuple[int, bytes]:
    """One GET on a keep-alive connection: (status, body)."""
    writer.write(f"GET {path} HTTP/1.1\r\nHost: bench\r\nAccept-Encoding: gzip\r\n\r\n".encode())
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.split(b"\r\n")
    status = int(lines[0].split()[1])
    length = 0
    for line in lines[1:]:
        if line[:15].lower() == b"content-length:":
            length = int(line[15:])
    return status, await reader.readexactly(length)


async def _client(url: str, sessions: asyncio.Queue, budget: list[int], log: list) -> None:
    u = urlsplit(url)
    reader, writer = await asyncio.open_connection(u.hostname, u.port)
    try:
        while budget[0] > 0:
            try:
                session = sessions.get_nowait()
            except asyncio.QueueEmpty:
                return
            for path in session:
                if budget[0] <= 0:
                    return
                budget[0] -= 1
                t0 = time.perf_counter()
                try:
                    status, _ = await asyncio.wait_for(_get(reader, writer, path), REQUEST_TIMEOUT)
                except (TimeoutError, OSError, asyncio.IncompleteReadError, ValueError) as exc:
                    log.append((path, type(exc).__name__, time.perf_counter() - t0))
                    writer.close()
                    reader, writer = await asyncio.open_connection(u.hostname, u.port)
                    continue
                log.append((path, status, time.perf_counter() - t0))
    finally:
        writer.close()


async def _run(url: str, sessions: list[list[str]], requests: int, clients: int) -> tuple:
    queue: asyncio.Queue = asyncio.Queue()
    for s in sessions:
        queue.put_nowait(s)
    log: list = []
    budget = [requests]
    t0 = time.perf_counter()
    await asyncio.wait_for(
        asyncio.gather(*[_client(url, queue, budget, log) for _ in range(clients)]), RUN_DEADLINE
    )
    return log, time.perf_counter() - t0


def run(url: str, sessions: list[list[str]], requests: int, clients: int) -> dict:
    """One load run: its figures."""
    log, seconds = asyncio.run(_run(url, sessions, requests, clients))
    lat = sorted(t for _, _, t in log)
    errors = [(p, s) for p, s, _ in log if s != 200]
    pct = lambda q: 1000 * lat[min(len(lat) - 1, int(q * len(lat)))] if lat else None  # noqa: E731
    return {
        "requests": len(log),
        "errors": len(errors),
        "error_examples": errors[:5],
        "seconds": seconds,
        "tiles_per_s": len(log) / seconds,
        "p50_ms": pct(0.50),
        "p90_ms": pct(0.90),
        "p99_ms": pct(0.99),
        "max_ms": 1000 * lat[-1] if lat else None,
        "latencies_ms": [round(1000 * t, 3) for t in lat],
    }


# -- the access pattern ------------------------------------------------------------------------


def fetch_json(url: str) -> dict:
    import urllib.request

    with urllib.request.urlopen(url, timeout=600) as r:
        data = r.read()
        if r.headers.get("content-encoding") == "gzip":
            import gzip

            data = gzip.decompress(data)
    return json.loads(data)


def available(ranges_by_level: list) -> dict[int, set[tuple[int, int]]]:
    out: dict[int, set[tuple[int, int]]] = {}
    for z, ranges in enumerate(ranges_by_level):
        for r in ranges:
            for y in range(r["startY"], r["endY"] + 1):
                for x in range(r["startX"], r["endX"] + 1):
                    out.setdefault(z, set()).add((x, y))
    return out


def geographic_tile(z: int, lon: float, lat: float) -> tuple[int, int]:
    size = 180.0 / 2**z
    return int((lon + 180.0) // size), int((lat + 90.0) // size)


def mercator_tile(z: int, lon: float, lat: float) -> tuple[int, int]:
    n = 2**z
    y = (1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n
    return int((lon + 180.0) / 360.0 * n), int(y)


def block(
    z: int, x: int, y: int, avail: dict[int, set[tuple[int, int]]]
) -> list[tuple[int, int, int]]:
    return [
        (z, x + dx, y + dy)
        for dy in (-1, 0, 1)
        for dx in (-1, 0, 1)
        if (x + dx, y + dy) in avail.get(z, ())
    ]


def tileset_paths(tile: dict, lon: float, lat: float, out: list[str]) -> None:
    """Content URIs of the tiles whose region holds (lon, lat) (radians), depth first."""
    w, s, e, n = tile["boundingVolume"]["region"][:4]
    if not (w <= lon <= e and s <= lat <= n):
        return
    if "content" in tile:
        out.append("/3dtiles/" + tile["content"]["uri"])
    for child in tile.get("children", []):
        tileset_paths(child, lon, lat, out)


def pattern(url: str, layer: str, requests: int, seed: int = 1) -> list[list[str]]:
    """Sessions (lists of paths) holding at least ``requests`` requests (module docstring)."""
    rng = random.Random(seed)
    base = url.rstrip("/")
    qm = fetch_json(base + "/terrain/layer.json")
    qm_avail = available(qm["available"])
    img = fetch_json(f"{base}/imagery/{layer}/tilejson.json")
    img_avail = available(img["approxtree"]["available"])
    dem = fetch_json(base + "/terrarium/tilejson.json")
    dem_avail = available(dem["approxtree"]["available"])
    merc = fetch_json(f"{base}/imagery/{layer}/webmercator/tilejson.json")
    merc_avail = available(merc["approxtree"]["available"])
    tileset = fetch_json(base + "/3dtiles/tileset.json")
    west, south, east, north = qm["bounds"]
    sessions: list[list[str]] = []
    total = 0
    while total < requests:
        lon, lat = rng.uniform(west, east), rng.uniform(south, north)
        kind = rng.choice(["cesium", "cesium", "maplibre", "3dtiles"])
        if kind == "cesium":
            deepest = rng.randint(max(qm["maxzoom"] - 3, 0), qm["maxzoom"])
            paths = ["/terrain/layer.json"]
            for z in range(deepest + 1):
                for zz, x, y in block(z, *geographic_tile(z, lon, lat), qm_avail):
                    paths.append(f"/terrain/{zz}/{x}/{y}.terrain")
                    if (x, y) in img_avail.get(z, ()):
                        paths.append(f"/imagery/{layer}/{zz}/{x}/{y}.png")
        elif kind == "maplibre":
            paths = ["/terrarium/tilejson.json"]
            for z in range(max(dem["maxzoom"], merc["maxzoom"]) + 1):
                for zz, x, y in block(z, *mercator_tile(z, lon, lat), dem_avail):
                    paths.append(f"/terrarium/{zz}/{x}/{y}.png")
                for zz, x, y in block(z, *mercator_tile(z, lon, lat), merc_avail):
                    paths.append(f"/imagery/{layer}/webmercator/{zz}/{x}/{y}.png")
        else:
            paths = ["/3dtiles/tileset.json"]
            tileset_paths(tileset["root"], math.radians(lon), math.radians(lat), paths)
        sessions.append(paths)
        total += len(paths)
    return sessions


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for name in ("cold", "cold_distinct", "warm"):
        lat = results["runs"][name]["latencies_ms"]
        if lat:
            a.plot(lat, [i / len(lat) for i in range(len(lat))], label=name)
    a.axvline(TARGETS["warm_p99_ms"], color="grey", ls=":", label="warm p99 target")
    a.set_xscale("log")
    a.set_xlabel("latency (ms)")
    a.set_ylabel("fraction of requests")
    a.legend()
    names = ["cold", "cold_distinct", "warm"]
    rates = [results["runs"][n]["tiles_per_s"] for n in names]
    b.bar(names, rates, color=["#c86", "#a64", "#68a"])
    b.axhline(TARGETS["warm_tiles_per_s"], color="#68a", ls=":", label="warm target")
    b.axhline(TARGETS["cold_tiles_per_s"], color="#c86", ls=":", label="cold target")
    b.set_ylabel("tiles / s")
    b.legend()
    fig.suptitle(
        f"approxtree serve, {results['requests']} requests, {results['clients']} clients "
        f"({results['machine']['cpus']} CPUs)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--requests", type=int, default=10000)
    p.add_argument("--clients", type=int, default=64)
    p.add_argument("--cache-mb", type=int, default=256)
    p.add_argument("--server-cpus", default=None, help="taskset CPU list for the server")
    p.add_argument("--store")
    p.add_argument("--textures")
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA)
    p.add_argument("--out", type=Path, default=RESULTS / "serve.json")
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_serve_"))
    try:
        store, textures = args.store, args.textures
        if store is None:
            store, textures = prepare(args.data_dir, tmp)
        layer = sorted(p.name for p in Path(textures).iterdir() if p.is_dir())[0]
        results: dict = {
            "requests": args.requests,
            "clients": args.clients,
            "cache_mb": args.cache_mb,
            "store": store,
            "textures": textures,
            "machine": {
                "cpus": os.cpu_count(),
                "platform": platform.platform(),
                "load_average_before": os.getloadavg(),
            },
            "server_cpus": args.server_cpus,
            "targets": TARGETS,
            "runs": {},
            "rss_mb": {},
        }
        try:
            import httptools  # noqa: F401
            import uvloop  # noqa: F401

            results["http"] = "httptools + uvloop"
        except ImportError:
            results["http"] = "h11 + asyncio (no httptools/uvloop)"
        # Cold: a fresh server, the pattern as it comes (its discovery documents first).
        server = Server(store, textures, args.cache_mb, args.server_cpus)
        try:
            results["rss_mb"]["start"] = server.rss_mb()
            t0 = time.perf_counter()
            sessions = pattern(server.url, layer, args.requests)
            results["discovery_seconds"] = time.perf_counter() - t0
            distinct_urls = {u for s in sessions for u in s}
            results["distinct_urls"] = len(distinct_urls)
            results["distinct_by_kind"] = {
                kind: sum(1 for u in distinct_urls if u.split("/")[1] == kind)
                for kind in ("terrain", "imagery", "terrarium", "3dtiles")
            }
            results["runs"]["cold"] = run(server.url, sessions, args.requests, args.clients)
            results["rss_mb"]["after_cold"] = server.rss_mb()
            results["runs"]["warm"] = run(server.url, sessions, args.requests, args.clients)
            results["rss_mb"]["after_warm"] = server.rss_mb()
            results["server_health"] = fetch_json(server.url + "health")
        finally:
            results["server_exit"] = server.stop()
        # Cold, distinct: every URL once on a fresh server (documents made first, as above).
        server = Server(store, textures, args.cache_mb, args.server_cpus)
        try:
            distinct = sorted({u for s in sessions for u in s})
            random.Random(2).shuffle(distinct)
            # Documents first (a client reads them before any tile), not timed.
            docs = [u for u in distinct if u.endswith(".json")]
            run(server.url, [docs], len(docs), 1)
            tiles = [[u] for u in distinct if not u.endswith(".json")]
            results["runs"]["cold_distinct"] = run(server.url, tiles, len(tiles), args.clients)
            results["rss_mb"]["after_cold_distinct"] = server.rss_mb()
        finally:
            server.stop()
        results["rss_mb"]["bound"] = args.cache_mb + TARGETS["rss_mb"]
        results["machine"]["load_average_after"] = os.getloadavg()
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
        plot(results, args.out.with_suffix(".png"))
        for name, r in results["runs"].items():
            print(
                f"{name:>13}: {r['requests']} requests, {r['errors']} errors, "
                f"{r['tiles_per_s']:.0f} tiles/s, p50 {r['p50_ms']:.1f} ms, "
                f"p99 {r['p99_ms']:.1f} ms"
            )
        print("RSS MB:", {k: round(v) for k, v in results["rss_mb"].items()}, "|", results["http"])
        print(f"Results: {args.out} and {args.out.with_suffix('.png')}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
