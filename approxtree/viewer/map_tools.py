"""Map tools of the viewer without a window: scale bar, north arrow, cursor readout,
distance measure, elevation profile and bookmarks.

Everything here works on a FrameState (the frame's own matrices) and the terrain, so the tools
are tested without GL. Lengths are in the terrain's display units at exaggeration 1
(``display_scale``: metres for geographic CRSs, the CRS unit otherwise).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.io.atomic import atomic_write

#: Samples of an elevation profile.
PROFILE_SAMPLES = 256


def nice_length(limit: float) -> float:
    """Largest 1, 2 or 5 × 10^k not above ``limit`` (> 0): the scale bar's length."""
    if not (limit > 0.0 and math.isfinite(limit)):
        return 0.0
    k = math.floor(math.log10(limit))
    for m in (5.0, 2.0, 1.0):
        if m * 10.0**k <= limit * (1 + 1e-12):
            return m * 10.0**k
    return 10.0 ** (k - 1) * 5.0


def format_length(metres: float, unit: str = "m") -> str:
    """'250 m', '2 km' (km from 1000 of a metre unit)."""
    if unit == "m" and metres >= 1000.0:
        return f"{metres / 1000.0:g} km"
    return f"{metres:g} {unit}"


def _ground_pixels(fs: Any, point: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Pixels (2, 2) of world ``point`` and ``point + step``."""
    px, _ = fs.world_to_pixels(np.stack([point, point + step]))
    return px


def scale_bar(
    fs: Any, point: np.ndarray, unit_scale: np.ndarray, max_px: float
) -> tuple[float, float]:
    """(length in display units, length in pixels) of a scale bar at world ``point`` (3,).

    The bar measures along the screen's horizontal through ``point``: one display unit east
    and one north are projected, the screen-x pixels per unit are combined, and the bar is
    the nicest length (``nice_length``) that fits in ``max_px`` pixels.
    """
    unit_scale = np.asarray(unit_scale, dtype=np.float64)
    east = _ground_pixels(fs, point, np.array([1.0 / unit_scale[0], 0.0, 0.0]))
    north = _ground_pixels(fs, point, np.array([0.0, 1.0 / unit_scale[1], 0.0]))
    # Pixels per display unit along the screen's x axis of a horizontal ground segment.
    dx_e, dx_n = east[1, 0] - east[0, 0], north[1, 0] - north[0, 0]
    dy_e, dy_n = east[1, 1] - east[0, 1], north[1, 1] - north[0, 1]
    # The ground direction that maps to screen-x: solve a·e + b·n ∝ (1, 0) in pixels.
    det = dx_e * dy_n - dx_n * dy_e
    if abs(det) < 1e-12:
        return 0.0, 0.0
    a, b = dy_n / det, -dy_e / det  # ground vector (units) whose image is (1 px, 0)
    units_per_px = math.hypot(a, b)
    length = nice_length(max_px * units_per_px)
    return length, length / units_per_px if units_per_px > 0 else 0.0


def north_angle(fs: Any, point: np.ndarray, unit_scale: np.ndarray) -> float:
    """Screen angle (degrees, clockwise from straight up) of the direction north at world
    ``point`` (3,): 0 when the camera looks north, 90 when north points right."""
    north = _ground_pixels(fs, point, np.array([0.0, 1.0 / float(unit_scale[1]), 0.0]))
    dx, dy = north[1] - north[0]  # pixels, y up
    return math.degrees(math.atan2(dx, dy)) % 360.0


@dataclass(frozen=True)
class Readout:
    """The map under one pixel: world x, y (CRS), drawn z (the mesh), h_T there, lon/lat."""

    x: float
    y: float
    z_drawn: float | None
    elevation: float
    lon: float | None = None
    lat: float | None = None

    def as_dict(self) -> dict[str, float | None]:
        return {
            "x": self.x,
            "y": self.y,
            "z_drawn": self.z_drawn,
            "elevation": self.elevation,
            "lon": self.lon,
            "lat": self.lat,
        }


class LonLat:
    """CRS → WGS84 lon/lat through pyproj (None when the terrain has no CRS)."""

    def __init__(self, crs: str | None) -> None:
        self.transformer = None
        if crs:
            from pyproj import Transformer

            self.transformer = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)

    def __call__(self, x: float, y: float) -> tuple[float | None, float | None]:
        if self.transformer is None:
            return None, None
        lon, lat = self.transformer.transform(x, y)
        return float(lon), float(lat)


def read_point(positions: np.ndarray, pixel: tuple[float, float]) -> np.ndarray | None:
    """World point (3,) drawn at image ``pixel`` (column, row from the top) of a Frame's
    positions (h, w, 4), or None where no terrain surface (or a skirt) is drawn."""
    h, w = positions.shape[:2]
    c, r = int(pixel[0]), int(pixel[1])
    if not (0 <= c < w and 0 <= r < h):
        return None
    p = positions[r, c]
    if not np.all(np.isfinite(p[:3])) or p[3] < 0.5:
        return None
    return p[:3].copy()


def ray_hit(
    terrain: Any,
    eye: np.ndarray,
    direction: np.ndarray,
    far: float,
    samples: int = 512,
    rounds: int = 3,
) -> np.ndarray | None:
    """First point (3,) world where the ray eye + t·direction (world units, t ≤ far) meets
    h_T, or None. Every round is one vectorized ``height_at`` call (``samples`` points over
    the bracket of the previous round's first crossing); the last bracket is interpolated
    linearly. (A bisection calls h_T once per step, ~20 ms each on a Grid.)"""
    lo, hi = 0.0, float(far)
    for _ in range(rounds):
        t = np.linspace(lo, hi, samples)
        p = eye[None, :] + t[:, None] * direction[None, :]
        above = p[:, 2] - terrain.height_at(p[:, 0], p[:, 1])
        below = np.nonzero(np.nan_to_num(above, nan=1.0) <= 0.0)[0]
        if len(below) == 0:
            return None
        k = int(below[0])
        if k == 0:
            return p[0]
        lo, hi, a0, a1 = t[k - 1], t[k], above[k - 1], above[k]
    f = a0 / (a0 - a1) if a0 != a1 else 0.0
    return eye + (lo + f * (hi - lo)) * direction


def readout(terrain: Any, point: np.ndarray, lonlat: LonLat, drawn: bool = True) -> Readout:
    """The readout of a world point: h_T at its (x, y) and its lon/lat; ``drawn``: the point
    is on the drawn mesh (its z is kept as z_drawn), else z_drawn is None."""
    x, y, z = (float(v) for v in point)
    h = float(terrain.height_at(np.array([x]), np.array([y]))[0])
    lon, lat = lonlat(x, y)
    return Readout(x, y, z if drawn else None, h, lon, lat)


def distances(a: np.ndarray, b: np.ndarray, unit_scale: np.ndarray) -> tuple[float, float]:
    """(horizontal, 3-D) distance between world points a, b (3,), display units at
    exaggeration 1."""
    d = (np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)) * unit_scale
    return float(np.hypot(d[0], d[1])), float(np.linalg.norm(d))


def profile(
    terrain: Any, a: np.ndarray, b: np.ndarray, unit_scale: np.ndarray, n: int = PROFILE_SAMPLES
) -> np.ndarray:
    """(n, 4) float64 samples (distance along the line, x, y, h_T) from a to b (world)."""
    t = np.linspace(0.0, 1.0, n)
    x = a[0] + t * (b[0] - a[0])
    y = a[1] + t * (b[1] - a[1])
    z = terrain.height_at(x, y)
    d = t * distances(a, b, unit_scale)[0]
    return np.column_stack([d, x, y, z])


def save_profile(samples: np.ndarray, path: str | os.PathLike, unit: str = "m") -> Path:
    """Write ``path`` (a PNG plot of elevation along the line) and the samples next to it
    (same name, .csv: distance, x, y, elevation). Returns the PNG path."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(7, 3), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    ax.fill_between(samples[:, 0], samples[:, 3], np.nanmin(samples[:, 3]), alpha=0.3)
    ax.plot(samples[:, 0], samples[:, 3], lw=1.5)
    ax.set_xlabel(f"distance ({unit})")
    ax.set_ylabel(f"elevation ({unit})")
    ax.set_title("Elevation profile")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png")
    csv = path.with_suffix(".csv")
    with atomic_write(csv) as f:
        np.savetxt(f, samples, delimiter=",", header="distance,x,y,elevation", fmt="%.17g")
    return path


def timestamp() -> str:
    """Local time to the millisecond for file names: "20250131-142500-042"."""
    return time.strftime("%Y%m%d-%H%M%S") + f"-{int(time.time() * 1e3) % 1000:03d}"


#: The file name of P's screenshots unless another is asked for (``screenshot_name``).
DEFAULT_SCREENSHOT_NAME = "approxtree-{time}.png"


def screenshot_name(pattern: str, n: int) -> str:
    """The file name of the ``n``-th screenshot (1, 2, ...) taken with P: ``pattern`` with
    {time} (``timestamp()``) and {n} filled in, e.g. "nc-{n:03d}.png" → "nc-001.png" (in the
    viewer's screenshot folder). InvalidParameterError for a pattern with other fields, a
    folder in it, or not ending in .png."""
    try:
        name = pattern.format(time=timestamp(), n=n)
    except (KeyError, IndexError, ValueError) as exc:
        raise InvalidParameterError(
            f"Bad screenshot name {pattern!r} ({exc}); use the fields {{time}} and {{n}}, e.g. "
            "'nc-{n:03d}.png'."
        ) from None
    if not name.lower().endswith(".png") or Path(name).name != name:
        raise InvalidParameterError(
            f"Bad screenshot name {pattern!r}: give a PNG file name (ending in .png, no "
            "folder); screenshots go to the screenshot folder."
        )
    return name


def default_bookmarks_path() -> Path:
    """``$XDG_CONFIG_HOME/approxtree/bookmarks.json`` (``~/.config`` without it)."""
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "approxtree" / "bookmarks.json"


class Bookmarks:
    """Named camera poses of one terrain, persisted in a JSON file shared by terrains:
    ``{source: {name: {"eye": [x, y, z], "target": [x, y, z]}}}`` (world coordinates)."""

    def __init__(self, path: str | os.PathLike, source: str) -> None:
        self.path = Path(path)
        self.source = source
        self._all: dict[str, dict[str, dict[str, list[float]]]] = {}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
            except json.JSONDecodeError as exc:
                raise InvalidParameterError(
                    f"Bookmark file {self.path} is not valid JSON ({exc}); fix or delete it."
                ) from exc
            if not isinstance(data, dict):
                raise InvalidParameterError(f"Bookmark file {self.path} must hold an object.")
            self._all = data

    @property
    def poses(self) -> dict[str, dict[str, list[float]]]:
        return self._all.setdefault(self.source, {})

    def names(self) -> list[str]:
        return list(self.poses)

    def save(self, name: str, eye: np.ndarray, target: np.ndarray) -> None:
        """Store the pose under ``name`` and write the file."""
        self.poses[name] = {"eye": [float(v) for v in eye], "target": [float(v) for v in target]}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(self.path) as f:
            f.write(json.dumps(self._all, indent=1).encode())

    def get(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in self.poses:
            known = ", ".join(self.names()) or "none"
            raise InvalidParameterError(f"No bookmark {name!r} (saved: {known}).")
        p = self.poses[name]
        return np.asarray(p["eye"], dtype=np.float64), np.asarray(p["target"], dtype=np.float64)
