"""Browser harness: CesiumJS in Debian's chromium (headless, WebGL via SwiftShader).

``run_views`` serves a tiles folder, the viewer page (examples/web) and CesiumJS's build from
web/node_modules on 127.0.0.1, opens one page per view through tests/web/shot.cjs
(playwright-core) and returns, per view, Cesium's statistics, the request log and the path of
the screenshot. ``cesium_view`` maps our Camera (eye, target, vertical fov in map units of
the terrain CRS) to Cesium's (position, direction, up in ECEF, through pyproj).
"""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
from pathlib import Path
from urllib.parse import urlencode, urlsplit

import numpy as np

REPO = Path(__file__).resolve().parents[1]
NODE_MODULES = REPO / "web" / "node_modules"
SHOT_SCRIPT = REPO / "tests" / "web" / "shot.cjs"
SERVE_SCRIPT = REPO / "examples" / "web" / "serve.py"
#: Background of the screenshots: a colour no shaded terrain has.
BACKGROUND = (255, 0, 255)


def chromium_path() -> str | None:
    """Debian's chromium executable, or None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def unavailable() -> str | None:
    """Why the browser tests cannot run here (None when they can)."""
    if shutil.which("node") is None:
        return "node is not installed"
    if chromium_path() is None:
        return "chromium is not installed (apt-get install chromium)"
    for package in ("cesium", "playwright-core"):
        if not (NODE_MODULES / package / "package.json").exists():
            return f"npm package {package} missing in web/node_modules (npm ci --prefix web)"
    return None


def _serve_module():
    """examples/web/serve.py as a module (the same server users run)."""
    spec = importlib.util.spec_from_file_location("approxtree_web_serve", SERVE_SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_views(
    tiles_dir: Path,
    views: list[dict],
    out_dir: Path,
    size: tuple[int, int] = (480, 320),
    timeout_s: float = 240.0,
    page: str = "index.html",
) -> list[dict]:
    """Open the viewer once per view; returns one dict per view (see tests/web/shot.cjs).
    page: a viewer page, index.html (CesiumJS) or maplibre.html (MapLibre GL JS, its npm= set
    to /npm/), or the path of a test page of tests/web served at /pages/ (which imports npm
    packages from /node_modules/).

    views: [{"name": str, "params": {url parameter: value}}]; the tiles folder is served at
    /tiles/, so params name it as "/tiles/tileset.json" or "/tiles/". Adds "screenshot" (the
    PNG path) and "tile_requests" (paths requested under /tiles/) to each result.
    """
    serve = _serve_module()
    out_dir.mkdir(parents=True, exist_ok=True)
    # A page of the viewer by name, or any served path (a test page under /pages/).
    path = page if page.startswith("/") else f"/viewer/{page}"
    roots = {
        **serve.default_roots(tiles_dir),
        "/pages/": REPO / "tests" / "web",
        "/node_modules/": NODE_MODULES,
    }
    with serve.TileServer(roots) as server:
        job_views = []
        for view in views:
            # MapLibre's page loads its packages from /npm/; the CesiumJS pages (the viewer and
            # the test pages) take CesiumJS and the background the terrain mask expects.
            if path == "/viewer/maplibre.html":
                defaults = {"npm": "/npm/"}
            else:
                defaults = {"cesium": "/cesium/", "bg": "#{:02x}{:02x}{:02x}".format(*BACKGROUND)}
            params = {**defaults, **view["params"]}
            job_views.append(
                {
                    "url": f"{server.url}{path}?{urlencode(params, safe='/,')}",
                    "screenshot": str(out_dir / f"{view['name']}.png"),
                }
            )
        job = {
            "node_modules": str(NODE_MODULES),
            "chromium": chromium_path(),
            "width": size[0],
            "height": size[1],
            "timeout_ms": int(timeout_s * 1000),
            "views": job_views,
        }
        job_path = out_dir / "job.json"
        job_path.write_text(json.dumps(job))
        proc = subprocess.run(
            ["node", str(SHOT_SCRIPT), str(job_path)],
            capture_output=True,
            text=True,
            timeout=timeout_s * len(views) + 60,
        )
    try:
        result = json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        raise RuntimeError(
            f"browser driver failed: {proc.stdout[-2000:]} {proc.stderr[-2000:]}"
        ) from exc
    if "error" in result:
        raise RuntimeError(f"browser driver failed: {result['error']}")
    for view, job_view, res in zip(views, job_views, result["views"], strict=True):
        res["name"] = view["name"]
        res["screenshot"] = job_view["screenshot"]
        paths = [urlsplit(u).path for u in res["requests"]]
        res["tile_requests"] = [p[len("/tiles/") :] for p in paths if p.startswith("/tiles/")]
    return result["views"]


def terrain_mask(
    png: Path | str, background: tuple[int, int, int] | None = BACKGROUND
) -> np.ndarray:
    """(H, W) bool: pixels that are not background. With background None, the alpha channel
    (approxtree render writes alpha 0 where no terrain is drawn)."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGBA"))
    if background is None:
        return img[..., 3] > 0
    diff = np.abs(img[..., :3].astype(np.int32) - np.array(background)).sum(axis=2)
    return diff > 24


def silhouette_distance(a: np.ndarray, b: np.ndarray) -> dict:
    """How far two terrain masks (H, W) bool differ: the fraction of pixels in their symmetric
    difference and the largest / 99th percentile distance (pixels) from a pixel in one mask but
    not the other to the nearest pixel of the other mask."""
    from scipy.ndimage import distance_transform_edt

    xor = a ^ b
    dist_to_a = distance_transform_edt(~a)
    dist_to_b = distance_transform_edt(~b)
    d = np.concatenate([dist_to_b[a & ~b], dist_to_a[b & ~a]])
    return {
        "xor_fraction": float(xor.mean()),
        "max_px": float(d.max()) if d.size else 0.0,
        "p99_px": float(np.percentile(d, 99)) if d.size else 0.0,
        "a_fraction": float(a.mean()),
        "b_fraction": float(b.mean()),
    }


def cesium_view(
    eye: tuple[float, float, float],
    target: tuple[float, float, float],
    fov: float,
    crs: str,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> dict[str, str]:
    """URL parameters placing Cesium's camera where our Camera.look_at(eye, target, fov) is.

    eye, target: map units of ``crs`` with z in metres (taken as ellipsoidal height, as the
    tile writers do). Position: eye in ECEF. Direction: towards the target's ECEF point. Up: the
    ECEF image of our up vector at the eye, made orthogonal to the direction. fov: our vertical
    field of view (degrees); the page converts it to Cesium's (horizontal when wider than high).
    """
    from pyproj import Transformer

    to_ecef = Transformer.from_crs(_crs_3d(crs), "EPSG:4978", always_xy=True)
    e = np.array(to_ecef.transform(*eye))
    t = np.array(to_ecef.transform(*target))
    u_end = np.array(to_ecef.transform(*(np.asarray(eye, float) + np.asarray(up, float))))
    d = (t - e) / np.linalg.norm(t - e)
    u = u_end - e
    u = u - np.dot(u, d) * d
    u /= np.linalg.norm(u)
    fmt = lambda v: ",".join(f"{x:.6f}" for x in v)  # noqa: E731
    return {"pos": fmt(e), "dir": fmt(d), "up": fmt(u), "vfov": f"{fov:g}"}


def _crs_3d(crs: str):
    """A 3D version of ``crs`` (heights in metres above the ellipsoid)."""
    from pyproj import CRS

    c = CRS.from_user_input(crs)
    return c.to_3d() if len(c.axis_info) < 3 else c


def lonlat_bounds(bounds: tuple[float, float, float, float], crs: str) -> tuple[float, ...]:
    """(west, south, east, north) degrees of a map-unit box (xmin, ymin, xmax, ymax)."""
    from pyproj import Transformer

    tr = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    return tr.transform_bounds(*bounds)


def tileset_depths(tileset_json: Path) -> dict[str, int]:
    """Content URI (relative to the tiles folder) -> depth of its tile, for an explicit tileset
    (external tilesets followed)."""
    depths: dict[str, int] = {}

    def walk(tile: dict, depth: int, folder: Path, base: Path) -> None:
        contents = tile.get("contents") or ([tile["content"]] if "content" in tile else [])
        for content in contents:
            uri = content.get("uri") or content.get("url")
            path = (folder / uri).resolve()
            rel = str(path.relative_to(base))
            depths[rel] = depth
            if uri.endswith(".json") and path.exists():
                walk(json.loads(path.read_text())["root"], depth, path.parent, base)
        for child in tile.get("children", []):
            walk(child, depth + 1, folder, base)

    base = tileset_json.parent.resolve()
    walk(json.loads(tileset_json.read_text())["root"], 0, base, base)
    return depths


def terrain_levels(tile_requests: list[str]) -> list[int]:
    """Levels z of the z/x/y.terrain tiles in a request log."""
    out = []
    for r in tile_requests:
        m = re.search(r"(?:^|/)(\d+)/\d+/\d+\.terrain$", r)
        if m:
            out.append(int(m.group(1)))
    return out
