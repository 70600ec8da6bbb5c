"""Serve `approxtree tiles` output and this viewer page on 127.0.0.1 (standard library only).

    python examples/web/serve.py OUT_DIR [--port 8000]

URL layout: /viewer/ is this folder, /tiles/ is OUT_DIR, /cesium/ is CesiumJS's Build/Cesium
and /npm/ the whole of web/node_modules (npm install --prefix web: MapLibre GL JS, pmtiles
for maplibre.html). It prints the URL to open. Unlike plain `python -m http.server`, it sends
.terrain files stored gzip-compressed with `Content-Encoding: gzip`, which
CesiumTerrainProvider needs, the MIME types of glTF, and answers byte ranges (206), which
PMTiles archives are read by. The browser tests (tests/browser.py) use the same server.
"""

from __future__ import annotations

import argparse
import http.server
import io
import os
import re
import threading
from pathlib import Path
from typing import ClassVar
from urllib.parse import unquote, urlsplit

HERE = Path(__file__).resolve().parent
NODE_MODULES = HERE.parent.parent / "web" / "node_modules"
CESIUM_BUILD = NODE_MODULES / "cesium" / "Build" / "Cesium"

# MIME types the defaults lack or get wrong for tiles.
TYPES = {
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".b3dm": "application/octet-stream",
    ".subtree": "application/octet-stream",
    ".json": "application/json",
    ".terrain": "application/vnd.quantized-mesh",
    ".js": "text/javascript",
    ".mjs": "text/javascript",
    ".wasm": "application/wasm",
    ".ktx2": "image/ktx2",
    ".webp": "image/webp",
}
GZIP_MAGIC = b"\x1f\x8b"


def make_handler(roots: dict[str, Path], log: list[str] | None = None):
    """A request handler serving each URL prefix ("/tiles/") from its folder."""

    class Handler(http.server.SimpleHTTPRequestHandler):
        extensions_map: ClassVar[dict[str, str]] = {
            **http.server.SimpleHTTPRequestHandler.extensions_map,
            **TYPES,
        }

        def translate_path(self, path: str) -> str:
            # Longest prefix first, so "/" can be a fallback root.
            url_path = unquote(urlsplit(path).path)
            for prefix in sorted(roots, key=len, reverse=True):
                if url_path.startswith(prefix):
                    rel = url_path[len(prefix) :]
                    root = roots[prefix].resolve()
                    full = (root / rel).resolve()
                    if full != root and root not in full.parents:
                        return str(root / "__outside__")
                    return str(full)
            return str(Path("/nonexistent"))

        def end_headers(self) -> None:
            # Tiles stored gzip-compressed on disk are sent as such, the browser inflates them.
            path = getattr(self, "_served", None)
            if path is not None and path.endswith(".terrain"):
                with open(path, "rb") as f:
                    if f.read(2) == GZIP_MAGIC:
                        self.send_header("Content-Encoding", "gzip")
            self.send_header("Access-Control-Allow-Origin", "*")
            self.send_header("Cache-Control", "no-store")
            super().end_headers()

        def send_head(self):
            self._served = self.translate_path(self.path)
            if log is not None:
                log.append(self.path)
            ranged = re.fullmatch(r"bytes=(\d*)-(\d*)", self.headers.get("Range", ""))
            if ranged and os.path.isfile(self._served) and any(ranged.groups()):
                return self._send_range(self._served, *ranged.groups())
            return super().send_head()

        def _send_range(self, path: str, first: str, last: str):
            """206 with the bytes asked for (``bytes=a-b``, ``a-``, ``-n``); 416 past the end."""
            size = os.path.getsize(path)
            start = int(first) if first else max(size - int(last), 0)
            end = min(int(last), size - 1) if first and last else size - 1
            if start >= size or end < start:
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{size}")
                self.end_headers()
                return None
            with open(path, "rb") as f:
                f.seek(start)
                data = f.read(end - start + 1)
            self.send_response(206)
            self.send_header("Content-Type", self.guess_type(path))
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Accept-Ranges", "bytes")
            self.end_headers()
            return io.BytesIO(data)

        def log_message(self, format: str, *args) -> None:
            pass

    return Handler


class TileServer:
    """A threaded HTTP server on 127.0.0.1 (port 0: any free port); use as a context manager.

    roots: URL prefix ("/tiles/") -> folder. requests: the paths requested, in order.
    """

    def __init__(self, roots: dict[str, Path | str], port: int = 0) -> None:
        self.requests: list[str] = []
        handler = make_handler({k: Path(v) for k, v in roots.items()}, self.requests)
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self) -> TileServer:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def default_roots(tiles_dir: Path | str) -> dict[str, Path]:
    """The URL layout of the viewer: /viewer/, /tiles/, /cesium/ and /npm/."""
    return {
        "/viewer/": HERE,
        "/tiles/": Path(tiles_dir),
        "/cesium/": CESIUM_BUILD,
        "/npm/": NODE_MODULES,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out_dir", help="output folder of `approxtree tiles`")
    parser.add_argument("--port", type=int, default=8000)
    args = parser.parse_args()
    out = Path(args.out_dir)
    server = TileServer(default_roots(out), args.port)
    kind = "tileset=/tiles/tileset.json" if (out / "tileset.json").exists() else "terrain=/tiles/"
    cesium = "&cesium=/cesium/" if CESIUM_BUILD.is_dir() else ""
    print(f"Open {server.url}/viewer/index.html?{kind}{cesium}  (Ctrl-C stops)")
    try:
        server.httpd.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.httpd.server_close()


if __name__ == "__main__":
    main()
