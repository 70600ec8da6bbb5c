"""Shading textures: cartographic hillshade and procedural morphology of a height grid.

``TopographicShading`` reproduces ``gdaldem hillshade`` (Horn or Zevenbergen–Thorne gradients,
azimuth, altitude, z factor, scale, -combined, -multidirectional) value for value, nodata
included; slope and curvature weights and cast shadows refine it for cartographic use.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError
from approxtree.geometry.grid import Grid
from approxtree.geometry.windowed import WindowedHeights
from approxtree.kernels import hillshade as hs
from approxtree.kernels.shadows import cast_shadows
from approxtree.textures.base import TextureData, grey_alpha_strips, grey_strips, grey_to_rgba

ALGORITHMS = {"horn": hs.HORN, "zevenbergen-thorne": hs.ZEVENBERGEN_THORNE}

#: Metres per degree used by gdaldem's documentation for geographic grids (-s 111120).
METRES_PER_DEGREE = 111120.0

#: Bytes of a windowed DEM's heights read ahead of the strip being shaded (at least 2 windows):
#: the reader reads on during numba's first dispatch (~1 s holding the GIL), within this bound.
_READ_AHEAD_BYTES = 64 * 2**20


def is_geographic(crs: str | None) -> bool:
    """True when the CRS has angular (degree) x and y."""
    if not crs:
        return False
    from rasterio.crs import CRS

    try:
        return bool(CRS.from_user_input(crs).is_geographic)
    except Exception:
        return False


class ShadingTexture(TextureData):
    """A grey texture computed from the heights of a Grid, on the grid's lattice."""

    def __init__(self, terrain: Grid) -> None:
        if not isinstance(terrain, Grid):
            raise InvalidParameterError(
                f"Shading needs a regular Grid, got a {type(terrain).__name__}; "
                "resample the data to a grid first."
            )
        self.terrain = terrain
        self.transform = terrain.transform
        self.shape = terrain.shape
        self.crs = terrain.crs

    def shade(self) -> np.ndarray:
        """(rows, cols) uint8 grey levels, 0 = nodata."""
        raise NotImplementedError

    def rgba(self) -> np.ndarray:
        return grey_to_rgba(self.shade())

    #: Grey textures: the pyramid stores grey and alpha (R = G = B).
    bands = 2

    def band_strips(self, rows: int) -> Iterator[np.ndarray]:
        # Streamed: only the grey levels are held whole, RGBA one strip at a time.
        return grey_strips(self.shade(), rows)

    def level_strips(self, rows: int) -> Iterator[np.ndarray]:
        return grey_alpha_strips(self.shade(), rows)


class TopographicShading(ShadingTexture):
    """Cartographic hillshade with gdaldem's meaning for every option.

    algorithm: "horn" or "zevenbergen-thorne". azimuth, altitude: light direction in degrees
    (azimuth clockwise from north). z_factor: vertical exaggeration. scale: horizontal units
    per z unit; None picks 111120 for geographic grids (degrees vs metres) and 1 otherwise.
    combined / multidirectional: gdaldem's -combined and -multidirectional.
    slope_weight in [0, 1] darkens steep slopes; curvature_weight in [0, 1] brightens ridges
    and darkens hollows; shadows casts the shadows of the light (both off for gdaldem output).
    """

    def __init__(
        self,
        terrain: Grid,
        algorithm: str = "horn",
        azimuth: float = 315.0,
        altitude: float = 45.0,
        z_factor: float = 1.0,
        scale: float | None = None,
        combined: bool = False,
        multidirectional: bool = False,
        slope_weight: float = 0.0,
        curvature_weight: float = 0.0,
        shadows: bool = False,
    ) -> None:
        super().__init__(terrain)
        if algorithm not in ALGORITHMS:
            raise InvalidParameterError(
                f"Unknown hillshade algorithm {algorithm!r}; choose one of {sorted(ALGORITHMS)}."
            )
        if combined and multidirectional:
            raise InvalidParameterError("combined and multidirectional exclude each other.")
        _check_light(azimuth, altitude, z_factor)
        for name, w in (("slope_weight", slope_weight), ("curvature_weight", curvature_weight)):
            if not 0.0 <= w <= 1.0:
                raise InvalidParameterError(f"{name} must lie in [0, 1], got {w}.")
        if scale is not None and not scale > 0:
            raise InvalidParameterError(f"scale must be > 0, got {scale}.")
        self.algorithm = algorithm
        self.azimuth = float(azimuth)
        self.altitude = float(altitude)
        self.z_factor = float(z_factor)
        self.scale = (
            float(scale)
            if scale is not None
            else (METRES_PER_DEGREE if is_geographic(terrain.crs) else 1.0)
        )
        self.combined = combined
        self.multidirectional = multidirectional
        self.slope_weight = slope_weight
        self.curvature_weight = curvature_weight
        self.shadows = shadows

    @property
    def _steps(self) -> tuple[float, float]:
        """(dx, signed dy) in z units, as gdaldem's geotransform[1], [5] times scale."""
        t = self.transform
        return t.a * self.scale, t.e * self.scale

    def hillshade(self) -> np.ndarray:
        """(rows, cols) float32 shade in [1, 255] (gdaldem before rounding), 0 = nodata."""
        return hs.hillshade(*self._kernel_args())

    def _plain_grey(self) -> np.ndarray:
        """``np.rint(self.hillshade())`` as (rows, cols) uint8: plain gdaldem output, rounded
        in the kernel without a float temporary of a large grid."""
        return hs.hillshade_grey(*self._kernel_args())

    def _heights(self) -> np.ndarray:
        """The whole (rows, cols) band the shading kernels read (WholeBandError if windowed
        and too large)."""
        return self.terrain.heights_array("topographic shading")

    def _kernel_args(self) -> tuple:
        """Arguments of the hillshade kernels: heights, steps, z factor, light, algorithm, mode."""
        return (self._heights(), *self._light_args())

    def _light_args(self) -> tuple:
        """``_kernel_args`` after the heights."""
        dx, dy = self._steps
        mode = hs.COMBINED if self.combined else hs.STANDARD
        if self.multidirectional:
            mode = hs.MULTIDIRECTIONAL
        light = (self.z_factor, self.altitude, self.azimuth)
        return (dx, dy, *light, ALGORITHMS[self.algorithm], mode)

    def slope(self) -> np.ndarray:
        """(rows, cols) float32 slope in degrees (gdaldem slope), NaN at nodata and border."""
        dx, dy = self._steps
        return hs.slope_degrees(self._heights(), dx, dy, self.z_factor, ALGORITHMS[self.algorithm])

    def curvature(self) -> np.ndarray:
        """(rows, cols) float32 Laplacian of height (1/z units): > 0 hollows, < 0 ridges."""
        dx, dy = self._steps
        return hs.profile_curvature(self._heights() * self.z_factor, dx, abs(dy))

    def shadow_mask(self) -> np.ndarray:
        """(rows, cols) bool: cells that the light cannot see."""
        dx, dy = self._steps
        return cast_shadows(self._heights() * self.z_factor, dx, dy, self.azimuth, self.altitude)

    def level_strips(self, rows: int) -> Iterator[np.ndarray]:
        if self.slope_weight or self.curvature_weight or self.shadows:
            return super().level_strips(rows)
        return self._plain_grey_alpha_strips(rows)

    def _plain_grey_alpha_strips(self, rows: int) -> Iterator[np.ndarray]:
        """Plain gdaldem grey levels and their alpha as (2, ≤ rows, cols) uint8 strips,
        each shaded on its own from the heights (no whole grey array): texel for texel the
        strips of ``grey_alpha_strips(self.shade(), rows)``."""
        args = self._light_args()
        height, width = self.shape
        # One strip buffer, reused: a strip is valid until the next is asked for (the
        # pyramid copies it), and fresh memory for each would be faulted in and zeroed.
        # Grey and alpha interleaved (rows, cols, 2), as the pyramid's spool stores texels:
        # the (2, n, cols) strip is a view of it, which the spool takes without a copy.
        buffer = np.empty((min(rows, height), width, 2), dtype=np.uint8)
        heights = self.terrain.heights
        if not isinstance(heights, WindowedHeights):
            z = self._heights()
            for r0 in range(0, height, rows):
                texels, strip = _strip(buffer, min(rows, height - r0))
                hs.hillshade_grey_alpha_rows(z, r0, texels, *args)
                yield strip
            return
        # Windowed heights: each strip's rows and one more at each end (the 3 × 3 window) are
        # read on a reader thread (GDAL, without the GIL) while the strip before is shaded, so
        # the band is never whole in memory. A window starting at the grid's first row, or
        # ending at its last, has that border row as its own: the kernel leaves it nodata.
        # Straight from the height source (as a block of the windowed heights reads): the
        # strips pass once, the block cache would only hold them.
        source = heights.source
        read_into = getattr(source, "read_into", None)
        starts = range(0, height, rows)
        window_bytes = (rows + 2) * width * np.dtype(heights.dtype).itemsize
        depth = max(2, _READ_AHEAD_BYTES // window_bytes)
        # Windows are queued ahead (up to _READ_AHEAD_BYTES): the reader keeps reading while
        # this thread loads the kernel. A source that reads into an array gets a ring of
        # depth + 1 buffers: window i reuses the buffer of window i − depth − 1, shaded
        # before window i is queued.
        ring = (
            [np.empty((min(rows + 2, height), width), heights.dtype) for _ in range(depth + 1)]
            if read_into is not None and np.dtype(source.dtype) == heights.dtype
            else None
        )

        def window(i: int) -> tuple[int, np.ndarray]:
            r0 = starts[i]
            a, b = max(r0 - 1, 0), min(r0 + rows + 1, height)
            if ring is not None and read_into is not None:
                return a, read_into(a, b, 0, width, ring[i % len(ring)][: b - a])
            z = np.asarray(source.read(a, b, 0, width), dtype=heights.dtype)
            return a, np.ascontiguousarray(z)

        count = len(starts)
        with ThreadPoolExecutor(1) as reader:
            ahead = deque(reader.submit(window, i) for i in range(min(depth, count)))
            for i, r0 in enumerate(starts):
                a, z = ahead.popleft().result()
                if i + depth < count:
                    ahead.append(reader.submit(window, i + depth))
                texels, strip = _strip(buffer, min(rows, height - r0))
                hs.hillshade_grey_alpha_rows(z, r0 - a, texels, *args)
                yield strip

    def shade(self) -> np.ndarray:
        if not (self.slope_weight or self.curvature_weight or self.shadows):
            return self._plain_grey()
        v = self.hillshade().astype(np.float64)
        valid = v > 0
        # Morphology darkens steep slopes and hollows multiplicatively, keeping nodata at 0.
        if self.slope_weight:
            s = np.nan_to_num(self.slope(), nan=0.0) / 90.0
            v = np.where(valid, 1.0 + (v - 1.0) * (1.0 - self.slope_weight * s), 0.0)
        if self.curvature_weight:
            k = np.nan_to_num(self.curvature(), nan=0.0)
            spread = np.percentile(np.abs(k[valid]), 95) if valid.any() else 0.0
            if spread > 0:
                k = np.clip(-k / spread, -1.0, 1.0)
                v = np.where(
                    valid, np.clip(v * (1.0 + 0.5 * self.curvature_weight * k), 1, 255), 0.0
                )
        if self.shadows:
            v = np.where(valid & self.shadow_mask(), np.maximum(1.0, 0.5 * v), v)
        return np.round(v).astype(np.uint8)


def _strip(buffer: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The first n rows of a reused (rows, cols, 2) uint8 buffer of grey + alpha texels: as
    the kernel's (n, cols) uint16 texels, and as the (2, n, cols) strip view."""
    rows = buffer[:n]
    return rows.view(np.uint16)[:, :, 0], rows.transpose(2, 0, 1)


def _check_light(azimuth: float, altitude: float, z_factor: float) -> None:
    """InvalidParameterError for a light direction or z factor no shading can use (an infinite
    z factor made NaN normals and a numpy warning, then a black texture)."""
    if not math.isfinite(azimuth):
        raise InvalidParameterError(f"azimuth must be a finite angle in degrees, got {azimuth}.")
    if not 0.0 <= altitude <= 90.0:
        raise InvalidParameterError(f"altitude must lie in [0, 90] degrees, got {altitude}.")
    if not (math.isfinite(z_factor) and z_factor > 0.0):
        raise InvalidParameterError(
            f"z_factor (--z-factor) must be a finite number > 0, got {z_factor}."
        )


def _light_vector(azimuth: float, altitude: float) -> np.ndarray:
    """Unit vector towards the light: azimuth clockwise from north, altitude above horizon."""
    az, alt = np.radians(azimuth), np.radians(altitude)
    return np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])


class _LitShading(ShadingTexture):
    """Shared parameters of the lighting-model shadings (Phong and Gouraud).

    Lighting: ambient + diffuse · max(0, n·l) + specular · max(0, n·h)^shininess with h the
    half vector between the light and a viewer straight above; grey = 1 + 254 · clamp(I, 0, 1).
    oversample: texels per grid cell along each axis (1 = one texel per data point).
    """

    def __init__(
        self,
        terrain: Grid,
        azimuth: float = 315.0,
        altitude: float = 45.0,
        z_factor: float = 1.0,
        scale: float | None = None,
        ambient: float = 0.15,
        diffuse: float = 0.85,
        specular: float = 0.0,
        shininess: float = 16.0,
        oversample: int = 1,
    ) -> None:
        super().__init__(terrain)
        if not (isinstance(oversample, int) and oversample >= 1):
            raise InvalidParameterError(f"oversample must be an integer >= 1, got {oversample!r}.")
        _check_light(azimuth, altitude, z_factor)
        self.light = _light_vector(azimuth, altitude)
        self.z_factor = float(z_factor)
        self.scale = (
            float(scale)
            if scale is not None
            else (METRES_PER_DEGREE if is_geographic(terrain.crs) else 1.0)
        )
        self.ambient, self.diffuse = float(ambient), float(diffuse)
        self.specular, self.shininess = float(specular), float(shininess)
        self.oversample = oversample
        rows, cols = terrain.shape
        # Oversampled texels subdivide each cell; texel centres stay inside the data lattice.
        self.shape = ((rows - 1) * oversample + 1, (cols - 1) * oversample + 1)
        t = terrain.transform
        self.transform = t @ Affine.translation(0.5 - 0.5 / oversample, 0.5 - 0.5 / oversample)
        self.transform = self.transform @ Affine.scale(1.0 / oversample)

    def vertex_normals(self) -> np.ndarray:
        """(rows, cols, 3) unit normals at the data points (central differences), NaN at holes."""
        z = self.terrain.heights_array("vertex normals").astype(np.float64) * self.z_factor
        t = self.terrain.transform
        dx, dy = t.a * self.scale, t.e * self.scale
        gx = np.full(z.shape, np.nan)
        gy = np.full(z.shape, np.nan)
        gx[:, 1:-1] = (z[:, 2:] - z[:, :-2]) / (2 * dx)
        gy[1:-1, :] = (z[2:, :] - z[:-2, :]) / (2 * dy)
        # One-sided differences on the border rows and columns.
        gx[:, 0], gx[:, -1] = (z[:, 1] - z[:, 0]) / dx, (z[:, -1] - z[:, -2]) / dx
        gy[0, :], gy[-1, :] = (z[1, :] - z[0, :]) / dy, (z[-1, :] - z[-2, :]) / dy
        n = np.stack([-gx, -gy, np.ones_like(z)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def intensity(self, normals: np.ndarray) -> np.ndarray:
        """Light intensity in [0, 1] for (..., 3) unit normals (NaN stays NaN)."""
        ndl = np.clip(normals @ self.light, 0.0, None)
        i = self.ambient + self.diffuse * ndl
        if self.specular:
            h = self.light + np.array([0.0, 0.0, 1.0])
            h /= np.linalg.norm(h)
            i = i + self.specular * np.clip(normals @ h, 0.0, None) ** self.shininess
        return np.clip(i, 0.0, 1.0)

    def _fine_lattice(self, values: np.ndarray) -> np.ndarray:
        """Linear interpolation of per-vertex values (rows, cols, k) onto the texel lattice."""
        from approxtree.kernels.grid_interp import grid_height_at

        k = self.oversample
        if k == 1:
            return values
        rows, cols = self.shape
        lattice_r, lattice_c = np.meshgrid(np.arange(rows) / k, np.arange(cols) / k, indexing="ij")
        fr, fc = lattice_r.ravel(), lattice_c.ravel()
        out = np.stack(
            [
                grid_height_at(np.ascontiguousarray(values[..., j]), fr, fc)
                for j in range(values.shape[-1])
            ],
            axis=-1,
        )
        return out.reshape(rows, cols, -1)

    @staticmethod
    def _grey(i: np.ndarray) -> np.ndarray:
        ok = np.isfinite(i)
        return np.where(ok, np.round(1.0 + 254.0 * np.nan_to_num(i)), 0).astype(np.uint8)


class PhongShading(_LitShading):
    """Per-pixel lighting: normals interpolated across each triangle, then lit per texel."""

    def shade(self) -> np.ndarray:
        n = self._fine_lattice(self.vertex_normals())
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        return self._grey(self.intensity(n))


class GouraudShading(_LitShading):
    """Per-vertex lighting: intensities computed at the data points, interpolated per texel."""

    def shade(self) -> np.ndarray:
        i = self.intensity(self.vertex_normals())
        return self._grey(self._fine_lattice(i[..., None])[..., 0])
