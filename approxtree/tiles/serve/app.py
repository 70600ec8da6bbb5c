"""The ASGI app (starlette): URL layout, HTTP semantics, errors.

URLs (``ROUTES``); every tile route answers GET and HEAD:

    /                                           the example viewer (a redirect to /viewer/...)
    /health                                     JSON: status, store, layers, cache figures
    /3dtiles/tileset.json, /3dtiles/{level}/{node}.glb
    /terrain/layer.json, /terrain/{z}/{x}/{y}.terrain          (quantized-mesh, gzip)
    /imagery/{layer}/tilejson.json, /imagery/{layer}/{z}/{x}/{y}.{png|webp|jpg}   (geographic)
    /imagery/{layer}/webmercator/tilejson.json, .../webmercator/{z}/{x}/{y}.{ext} (XYZ)
    /terrarium/tilejson.json, /terrarium/{z}/{x}/{y}.{png|webp}
    /terrain-rgb/tilejson.json, /terrain-rgb/{z}/{x}/{y}.{png|webp}
        (the imagery and raster-dem sets of PMTiles archives at the same URLs: ``archives``)
    /viewer/..., /cesium/...                    examples/web and CesiumJS's build, when present

HTTP: a strong ETag per entity (``cache.Entry``), If-None-Match → 304; gzip to clients that
accept it for JSON, GLB and quantized-mesh (stored gzip: identity only to those that refuse
it), ``Vary: Accept-Encoding``; ``Cache-Control`` (tiles an hour, documents revalidated);
CORS for every origin (``Access-Control-Allow-Origin: *``, preflight answered). Errors are
JSON ``{"error": message}``: 404 for what the server does not have (``NotServed``, unknown
paths), 400 for bad parameters, 503 when too many tiles are being made (``Busy``), 500 with
the ApproxTreeError's message (a damaged store chunk: its StoreError), and 500 "internal
error" for anything else, logged with its traceback on the server, never sent.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import RedirectResponse, Response
from starlette.routing import BaseRoute, Mount, Route
from starlette.staticfiles import StaticFiles

from approxtree.errors import ApproxTreeError, InvalidParameterError
from approxtree.tiles.serve.cache import Busy, Entry, TileCache
from approxtree.tiles.serve.service import JSON, NotServed, TileService
from approxtree.tiles.tileset3d import tile_uri

log = logging.getLogger("approxtree.serve")

#: The repository's viewer page and CesiumJS build (a source checkout; absent in a wheel).
REPO = Path(__file__).resolve().parents[3]
VIEWER = REPO / "examples" / "web"
CESIUM = REPO / "web" / "node_modules" / "cesium" / "Build" / "Cesium"
#: Cache-Control of tiles (immutable while the store is) and of documents (revalidated).
TILE_CACHING = "public, max-age=3600"
DOCUMENT_CACHING = "no-cache"
CORS = {
    "access-control-allow-origin": "*",
    "access-control-expose-headers": "ETag, Content-Encoding, Content-Length",
}


def _accepts_gzip(request: Request) -> bool:
    """Whether Accept-Encoding takes gzip (named, or ``*``, with a q above 0)."""
    for part in request.headers.get("accept-encoding", "").split(","):
        name, _, params = part.strip().partition(";")
        if name.strip().lower() in ("gzip", "*"):
            q = params.strip().removeprefix("q=").strip() if "q=" in params else "1"
            try:
                return float(q) > 0
            except ValueError:
                return False
    return False


def respond(request: Request, entry: Entry, caching: str) -> Response:
    """The 200 (or 304) response of an entry for this request."""
    body, encoding, etag = entry.representation(_accepts_gzip(request))
    headers = {"etag": etag, "cache-control": caching, **CORS}
    if entry.gzip is not None or entry.gzipped:
        headers["vary"] = "Accept-Encoding"
    inm = request.headers.get("if-none-match")
    if inm is not None and entry.matches(inm):
        return Response(status_code=304, headers=headers)
    if encoding is not None:
        headers["content-encoding"] = encoding
    return Response(body, media_type=entry.media_type, headers=headers)


def error(status: int, message: str) -> Response:
    body = json.dumps({"error": message, "status": status}).encode()
    return Response(body, status_code=status, media_type=JSON, headers=dict(CORS))


async def _answer(make: Callable[[], Awaitable[Response]]) -> Response:
    """``make()``'s response, or the error response of what it raised (module docstring)."""
    try:
        return await make()
    except NotServed as exc:
        return error(404, str(exc))
    except InvalidParameterError as exc:
        return error(400, str(exc))
    except Busy as exc:
        response = error(503, str(exc))
        response.headers["retry-after"] = "1"
        return response
    except ApproxTreeError as exc:
        log.warning("%s", exc)
        return error(500, str(exc))
    except Exception:
        log.exception("internal error")
        return error(500, "Internal error of the tile server (its log has the details).")


class TileApp:
    """The endpoints over one TileService (module docstring)."""

    def __init__(self, service: TileService, cache: TileCache, workers: int) -> None:
        self.service = service
        self.cache = cache
        self.workers = workers

    async def _tile(self, request: Request, key: Any, make: Callable[[], Entry], caching: str):
        async def run() -> Response:
            return respond(request, await self.cache.get_or_make(key, make), caching)

        return await _answer(run)

    async def tileset(self, request: Request) -> Response:
        s = self.service
        return await self._tile(
            request,
            ("3dtiles", "tileset.json"),
            lambda: s.tileset(self.cache, self.cache.executor, self.workers),
            DOCUMENT_CACHING,
        )

    async def glb(self, request: Request) -> Response:
        level, node = request.path_params["level"], request.path_params["node"]
        key = ("3dtiles", tile_uri(level, node))
        return await self._tile(request, key, lambda: self.service.glb(level, node), TILE_CACHING)

    async def layer(self, request: Request) -> Response:
        return await self._tile(
            request, ("terrain", "layer.json"), self.service.layer_json, DOCUMENT_CACHING
        )

    async def terrain(self, request: Request) -> Response:
        z, x, y = (request.path_params[k] for k in "zxy")
        key = ("terrain", z, x, y)
        return await self._tile(
            request, key, lambda: self.service.terrain_tile(z, x, y), TILE_CACHING
        )

    def _map(self, kind: str, scheme: str):
        """The tile and TileJSON endpoints of a map tile set."""

        async def tile(request: Request) -> Response:
            p = request.path_params
            layer, z, x, y, ext = p.get("layer"), p["z"], p["x"], p["y"], p["ext"]
            key = (kind, layer, scheme, z, x, y, ext)
            make = lambda: self.service.map_tile(kind, layer, scheme, z, x, y, ext)  # noqa: E731
            return await self._tile(request, key, make, TILE_CACHING)

        async def document(request: Request) -> Response:
            layer = request.path_params.get("layer")
            base = str(request.url).rsplit("/", 1)[0] + "/"
            key = (kind, layer, scheme, "tilejson", base)
            make = lambda: Entry.made(JSON, self.service.map_tilejson(kind, layer, scheme, base))  # noqa: E731
            return await self._tile(request, key, make, DOCUMENT_CACHING)

        return tile, document

    async def health(self, request: Request) -> Response:
        doc = {
            "status": "ok",
            "store": self.service.store,
            "layers": self.service.layers,
            "archives": self.service.archive_urls,
            "cache": self.cache.stats(),
        }
        return Response(
            json.dumps(doc).encode(), media_type=JSON, headers={"cache-control": "no-store", **CORS}
        )

    async def viewer(self, request: Request) -> Response:
        if not (VIEWER / "index.html").is_file():
            return error(
                404,
                "The viewer page ships with the source repository (examples/web); the tiles "
                "are at /terrain/layer.json, /3dtiles/tileset.json and /imagery/.",
            )
        params = {"terrain": "/terrain/"}
        if self.service.layers:
            params["imagery"] = f"/imagery/{self.service.layers[0]}/tilejson.json"
        if (CESIUM / "Cesium.js").is_file():
            params["cesium"] = "/cesium/"
        return RedirectResponse("/viewer/index.html?" + urlencode(params, safe="/"), 307)

    def routes(self) -> list[BaseRoute]:
        int_zxy = "{z:int}/{x:int}/{y:int}"
        out: list[BaseRoute] = [
            Route("/", self.viewer),
            Route("/health", self.health),
            Route("/3dtiles/tileset.json", self.tileset),
            Route("/3dtiles/{level:int}/{node:int}.glb", self.glb),
            Route("/terrain/layer.json", self.layer),
            Route(f"/terrain/{int_zxy}.terrain", self.terrain),
        ]
        sets = [
            ("/imagery/{layer}", "imagery", "geographic"),
            ("/imagery/{layer}/webmercator", "imagery", "webmercator"),
            ("/terrarium", "terrarium", "webmercator"),
            ("/terrain-rgb", "terrain-rgb", "webmercator"),
        ]
        for prefix, kind, scheme in sets:
            tile, document = self._map(kind, scheme)
            out.append(Route(f"{prefix}/tilejson.json", document))
            out.append(Route(f"{prefix}/{int_zxy}.{{ext}}", tile))
        if VIEWER.is_dir():
            out.append(Mount("/viewer", StaticFiles(directory=VIEWER)))
        if CESIUM.is_dir():
            out.append(Mount("/cesium", StaticFiles(directory=CESIUM)))
        return out


class _Preflight:
    """ASGI middleware: CORS preflight (OPTIONS) answered for every path, 204."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http" or scope["method"] != "OPTIONS":
            await self.app(scope, receive, send)
            return
        asked = dict(scope["headers"]).get(b"access-control-request-headers", b"*")
        headers = [(k.encode(), v.encode()) for k, v in CORS.items()]
        headers += [
            (b"access-control-allow-methods", b"GET, HEAD, OPTIONS"),
            (b"access-control-allow-headers", asked),
            (b"access-control-max-age", b"86400"),
        ]
        await send({"type": "http.response.start", "status": 204, "headers": headers})
        await send({"type": "http.response.body", "body": b""})


def create_app(
    store: str | None,
    textures: str | None = None,
    cache_bytes: int = 256 << 20,
    workers: int = 2,
    max_pending: int = 256,
    archives: list[str] | None = None,
) -> Any:
    """The ASGI app serving the tiles of the tree store ``store`` (module docstring).

    textures: a texture pyramid folder or a folder of them (imagery layers); cache_bytes: the
    tile cache's bound; workers: threads making tiles; max_pending: tiles made or queued at
    once before requests get 503; archives: PMTiles files whose tiles are served as stored
    (``serve/archives.py``); ``store`` may be None when they are given.
    """
    if not (isinstance(cache_bytes, int) and cache_bytes > 0):
        raise InvalidParameterError(f"cache_bytes must be an int > 0, got {cache_bytes!r}.")
    if not (isinstance(workers, int) and workers >= 1):
        raise InvalidParameterError(f"workers must be an int >= 1, got {workers!r}.")
    service = TileService(store, textures, archives)
    executor = ThreadPoolExecutor(workers, thread_name_prefix="approxtree-tiles")
    cache = TileCache(cache_bytes, executor, max_pending)
    tiles = TileApp(service, cache, workers)

    @asynccontextmanager
    async def lifespan(app: Starlette):
        yield
        # Shutdown: tiles not started are dropped, running ones finish on their threads.
        executor.shutdown(wait=False, cancel_futures=True)
        service.close()

    async def http_error(request: Request, exc: Exception) -> Response:
        # Unknown paths (404) and methods (405) as JSON errors too.
        status = exc.status_code if isinstance(exc, HTTPException) else 500
        detail = exc.detail if isinstance(exc, HTTPException) else "internal error"
        return error(status, f"{detail}: {request.url.path[:200]}")

    app = Starlette(
        routes=tiles.routes(), lifespan=lifespan, exception_handlers={HTTPException: http_error}
    )
    app.state.tiles = tiles
    return _Preflight(app)
