"""EarthFrame: where terrain coordinates lie on the WGS84 ellipsoid (ECEF, EPSG:4978).

Web clients place everything in earth-centred, earth-fixed metres. Terrain with a CRS goes
through pyproj: map x, y in the CRS and z as the height above the ellipsoid (a DEM's heights
are usually above the geoid; the difference, tens of metres, shifts the whole tileset and is
not corrected). Terrain without a CRS is placed in a local east-north-up frame: x, y, z in
metres, the domain's centre at (lon, lat) = ``origin`` (default 0, 0) on the ellipsoid:
ECEF = ``enu_matrix`` @ (x − cx, y − cy, z, 1).

With a CRS, pyproj takes points to WGS84 longitude, latitude and height (EPSG:4979) and the
closed-form geodetic → ECEF formula does the rest (one pyproj call per tile serves both the
ECEF positions and the tile's region).

pyproj transformers are not thread-safe: each thread gets its own (``threading.local``).
"""

from __future__ import annotations

import math
import threading

import numpy as np

from approxtree.errors import InvalidParameterError

#: WGS84 semi-major and semi-minor axes (m).
WGS84_A = 6378137.0
WGS84_B = 6356752.314245179


def geodetic_to_ecef(lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(n, 3) ECEF metres of WGS84 longitudes, latitudes (degrees) and heights (m)."""
    lam, phi = np.radians(lon), np.radians(lat)
    e2 = 1.0 - (WGS84_B / WGS84_A) ** 2
    n = WGS84_A / np.sqrt(1.0 - e2 * np.sin(phi) ** 2)
    return np.column_stack(
        [
            (n + h) * np.cos(phi) * np.cos(lam),
            (n + h) * np.cos(phi) * np.sin(lam),
            (n * (1.0 - e2) + h) * np.sin(phi),
        ]
    )


def enu_matrix(lon: float, lat: float, height: float = 0.0) -> np.ndarray:
    """(4, 4) float64 local east-north-up metres → ECEF at (lon, lat, height) (degrees, m)."""
    lam, phi = math.radians(lon), math.radians(lat)
    east = np.array([-math.sin(lam), math.cos(lam), 0.0])
    north = np.array(
        [-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi)]
    )
    up = np.array([math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi)])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = east, north, up
    m[:3, 3] = geodetic_to_ecef(np.array([lon]), np.array([lat]), np.array([height]))[0]
    return m


class EarthFrame:
    """Terrain coordinates → ECEF (see the module docstring).

    crs: the terrain's CRS (EPSG code or WKT) or None; center: (cx, cy) of the domain (used
    without a CRS); origin: (lon, lat) in degrees of the local frame (without a CRS).
    """

    def __init__(
        self,
        crs: str | None,
        center: tuple[float, float],
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.crs = crs
        self.center = (float(center[0]), float(center[1]))
        self.origin = (float(origin[0]), float(origin[1]))
        if not (-180.0 <= self.origin[0] <= 180.0 and -90.0 < self.origin[1] < 90.0):
            raise InvalidParameterError(
                f"--origin must be a longitude in [-180, 180] and a latitude in (-90, 90) "
                f"degrees, got {origin!r}."
            )
        self._local = threading.local()
        if crs is not None:
            from pyproj import CRS
            from pyproj.exceptions import CRSError

            try:
                CRS.from_user_input(crs)
            except CRSError as exc:
                raise InvalidParameterError(
                    f"The terrain's CRS is not understood by pyproj ({exc}); rebuild the tree "
                    "from a file with a valid CRS, or from one without a CRS (local frame)."
                ) from exc
        #: (4, 4) local frame → ECEF (identity for terrain with a CRS: vertices go to ECEF).
        self.matrix = np.eye(4) if crs is not None else enu_matrix(*self.origin)

    def __reduce__(self):
        # Pickled (to dask workers) by its arguments: the per-thread transformers stay here.
        return (EarthFrame, (self.crs, self.center, self.origin))

    @property
    def georeferenced(self) -> bool:
        return self.crs is not None

    def _transformer(self, target: str):
        """This thread's pyproj transformer from the terrain's CRS to ``target``."""
        from pyproj import Transformer

        cache = self._local.__dict__.setdefault("transformers", {})
        t = cache.get(target)
        if t is None:
            t = Transformer.from_crs(self.crs, target, always_xy=True)
            cache[target] = t
        return t

    def to_frame(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float64: terrain points (n, 3) in the tileset frame — ECEF metres with a
        CRS, local east-north-up metres (domain centre at 0, 0) without."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.crs is None:
            return np.column_stack([p[:, 0] - self.center[0], p[:, 1] - self.center[1], p[:, 2]])
        geo = self.to_geodetic(p)
        return geodetic_to_ecef(geo[:, 0], geo[:, 1], geo[:, 2])

    def to_geodetic(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float64 WGS84 longitude, latitude (degrees) and ellipsoidal height (m) of
        terrain points (n, 3); only for terrain with a CRS."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        lon, lat, h = self._transformer("EPSG:4979").transform(p[:, 0], p[:, 1], p[:, 2])
        return np.column_stack([lon, lat, h])

    def from_ecef(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float64 terrain coordinates of ECEF points (n, 3) (the inverse of
        ``to_frame`` followed by ``matrix``)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.crs is None:
            m = self.matrix
            local = (p - m[:3, 3]) @ m[:3, :3]  # the rotation's inverse is its transpose
            return local + np.array([self.center[0], self.center[1], 0.0])
        from pyproj import Transformer

        t = Transformer.from_crs("EPSG:4978", self.crs, always_xy=True)
        x, y, z = t.transform(p[:, 0], p[:, 1], p[:, 2])
        return np.column_stack([x, y, z])
