"""Sample terrains: the real DEM shipped inside matplotlib, and seeded fractal terrain.

``sample_terrain()`` is the Jacksboro fault DEM (Tennessee, USGS 3″ data, 344 × 403) that ships
with matplotlib, so the demo needs no download. ``fractal_terrain()`` makes reproducible
fractional-Brownian surfaces of any size for benchmarks and scale tests. ``FractalHeights`` and
``write_fractal_terrain()`` make DEMs bigger than memory: heights are a pure function of
(row, col, seed), computed and written block by block (a tiled, compressed GeoTIFF or COG).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, TerrainFormatError
from approxtree.geometry.grid import Grid


def sample_terrain_path() -> Path:
    """Path of matplotlib's ``jacksboro_fault_dem.npz``."""
    import matplotlib

    path = Path(matplotlib.get_data_path()) / "sample_data" / "jacksboro_fault_dem.npz"
    if not path.is_file():
        raise TerrainFormatError(
            f"matplotlib's sample DEM is missing at {path}; reinstall matplotlib "
            "(pip install --force-reinstall matplotlib)."
        )
    return path


def sample_terrain() -> Grid:
    """The Jacksboro fault DEM: 344 × 403 int16 heights in metres, 3″ cells, EPSG:4326.

    Row 0 is north. The file stores its bounds with ymin and ymax swapped; the pair is sorted
    here so the domain is right.
    """
    with np.load(sample_terrain_path()) as f:
        z = f["elevation"]
        xmin, xmax = sorted((float(f["xmin"]), float(f["xmax"])))
        ymin, ymax = sorted((float(f["ymin"]), float(f["ymax"])))
    rows, cols = z.shape
    transform = Affine((xmax - xmin) / cols, 0.0, xmin, 0.0, -(ymax - ymin) / rows, ymax)
    return Grid(z, transform=transform, crs="EPSG:4326")


def fractal_heights(
    rows: int,
    cols: int | None = None,
    seed: int = 0,
    hurst: float = 0.8,
    relief: float = 1000.0,
) -> np.ndarray:
    """Fractional-Brownian height field by spectral synthesis: (rows, cols) float32.

    The amplitude spectrum falls as f^−(hurst + 1), so the surface has the same roughness at
    every scale; heights are scaled to span [0, relief].
    """
    cols = rows if cols is None else cols
    if rows < 2 or cols < 2:
        raise InvalidParameterError(
            f"A fractal terrain needs at least 2 × 2 points, got {rows} × {cols}."
        )
    if not 0.0 < hurst < 1.0:
        raise InvalidParameterError(f"hurst must lie in (0, 1), got {hurst}.")
    from scipy import fft

    rng = np.random.default_rng(seed)
    fy = fft.fftfreq(rows)[:, None]
    fx = fft.rfftfreq(cols)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amplitude = f ** -(hurst + 1.0)
    amplitude[0, 0] = 0.0
    # Random phases with Gaussian amplitudes give a Gaussian field with that spectrum.
    spectrum = amplitude * (
        rng.standard_normal(amplitude.shape) + 1j * rng.standard_normal(amplitude.shape)
    )
    del f, amplitude
    z = fft.irfft2(spectrum, s=(rows, cols), workers=-1)
    del spectrum
    z -= z.min()
    z *= relief / max(z.max(), 1e-12)
    return z.astype(np.float32)


def fractal_terrain(
    rows: int,
    cols: int | None = None,
    seed: int = 0,
    hurst: float = 0.8,
    relief: float = 1000.0,
    cell_size: float = 10.0,
) -> Grid:
    """A seeded fractal Grid of any size with square cells of ``cell_size`` metres.

    No CRS: x and y are metres from the north-west corner at (0, rows × cell_size). Held in
    memory whole; for DEMs bigger than memory see ``write_fractal_terrain``.
    """
    z = fractal_heights(rows, cols, seed=seed, hurst=hurst, relief=relief)
    transform = Affine(cell_size, 0.0, 0.0, 0.0, -cell_size, z.shape[0] * cell_size)
    return Grid(z, transform=transform)


#: (wavelengths, amplitudes, offsets (k, 2), salts) of the k octaves of one noise field.
Octaves = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class FractalHeights:
    """Seeded multi-octave gradient noise, read window by window: a ``HeightSource``.

    Heights (metres) are ``relief + Σ_k a_k · noise_k(row, col)`` over octaves of wavelength
    ``wavelength / 2^k`` cells down to 2 cells, with amplitude a_k = relief · (λ_k /
    wavelength)^hurst: the same roughness at every scale, about ±relief in all. They depend on
    (row, col, seed) and the parameters only, never on ``shape``: a window of a big raster equals
    the same window of a small one. ``holes`` (0 ≤ holes < 1) is about the fraction of cells that
    are nodata (NaN), in blobs of about wavelength / 8 cells. Pickles as its parameters.
    """

    shape: tuple[int, int]
    seed: int = 0
    hurst: float = 0.9
    relief: float = 500.0
    wavelength: float = 8192.0
    holes: float = 0.0
    dtype: np.dtype = field(default=np.dtype(np.float32), init=False)

    def __post_init__(self) -> None:
        shape = tuple(self.shape)
        if (
            len(shape) != 2
            or not all(isinstance(n, int | np.integer) and not isinstance(n, bool) for n in shape)
            or min(shape) < 2
        ):
            raise InvalidParameterError(
                f"A fractal terrain needs at least 2 × 2 points, got shape {self.shape!r}; "
                "give whole numbers of rows and columns ≥ 2."
            )
        object.__setattr__(self, "shape", (int(shape[0]), int(shape[1])))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
            raise InvalidParameterError(f"seed must be a whole number, got {self.seed!r}.")
        if not 0.0 < self.hurst < 1.5:
            raise InvalidParameterError(f"hurst must lie in (0, 1.5), got {self.hurst}.")
        if not (math.isfinite(self.relief) and self.relief > 0.0):
            raise InvalidParameterError(f"relief must be a positive height, got {self.relief}.")
        if not (math.isfinite(self.wavelength) and self.wavelength >= 4.0):
            raise InvalidParameterError(
                f"wavelength must be at least 4 cells, got {self.wavelength}."
            )
        if not 0.0 <= self.holes < 1.0:
            raise InvalidParameterError(
                f"holes is the fraction of nodata cells, in [0, 1); got {self.holes}."
            )

    @property
    def nodata(self) -> float | None:
        """NaN when the terrain has holes, else None."""
        return math.nan if self.holes > 0 else None

    def _octaves(self, salt: int, wavelength: float, count: int | None = None) -> Octaves:
        """(wavelengths, amplitudes, offsets, salts) of the octaves of one noise field."""
        from approxtree.kernels.noise import mix64

        k = np.arange(count if count is not None else max(1, int(math.log2(wavelength / 2)) + 1))
        lengths = wavelength / 2.0**k
        amplitudes = self.relief * (lengths / wavelength) ** self.hurst
        seed = np.uint64(int(self.seed) & (2**64 - 1))
        salts = np.array(
            [mix64(seed ^ mix64(np.uint64(salt * 1000 + i + 1))) for i in k], dtype=np.uint64
        )
        # Lattice shifts of a fraction of the wavelength, from the salt's low bits.
        frac = np.column_stack([(salts >> np.uint64(s)) & np.uint64(0xFFFF) for s in (16, 32)])
        offsets = frac / 65536.0 * lengths[:, None]
        return lengths, amplitudes, offsets, salts

    def _noise(
        self, r0: int, c0: int, out: np.ndarray, octaves: Octaves, base: float
    ) -> np.ndarray:
        from approxtree.kernels.noise import gradient_noise_block

        wavelengths, amplitudes, offsets, salts = octaves
        gradient_noise_block(r0, c0, out, wavelengths, amplitudes, offsets, salts, base)
        return out

    @functools.cached_property
    def _hole_threshold(self) -> float:
        """The mask level above which a cell is a hole: the (1 − holes) quantile of the mask
        noise on a fixed sample of cells (it depends on the parameters only, not the window)."""
        octaves = self._octaves(1, self.wavelength / 8.0, 2)
        # 256 × 256 cells spread over 64 × 64 mask wavelengths (many blobs).
        step = max(1, int(self.wavelength / 64))
        row = np.empty((1, 256 * step))
        sample = np.empty((256, 256))
        for i in range(256):
            sample[i] = self._noise(i * step, 0, row, octaves, 0.0)[0, ::step]
        return float(np.quantile(sample, 1.0 - self.holes))

    def read(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Heights of rows [r0, r1) and columns [c0, c1): (r1 − r0, c1 − c0) float32, NaN for
        nodata. Windows may reach beyond ``shape`` (the noise goes on)."""
        if not (0 <= r0 <= r1 and 0 <= c0 <= c1):
            raise InvalidParameterError(
                f"A window needs 0 ≤ r0 ≤ r1 and 0 ≤ c0 ≤ c1, got rows [{r0}, {r1}), "
                f"columns [{c0}, {c1})."
            )
        out = np.empty((r1 - r0, c1 - c0), dtype=np.float32)
        self._noise(r0, c0, out, self._octaves(0, self.wavelength), self.relief)
        if self.holes > 0:
            mask = np.empty(out.shape, dtype=np.float32)
            self._noise(r0, c0, mask, self._octaves(1, self.wavelength / 8.0, 2), 0.0)
            out[mask > self._hole_threshold] = np.nan
        return out


def write_fractal_terrain(
    path: str | os.PathLike,
    rows: int,
    cols: int | None = None,
    *,
    seed: int = 0,
    hurst: float = 0.9,
    relief: float = 500.0,
    wavelength: float = 8192.0,
    holes: float = 0.0,
    cell_size: float = 1.0,
    crs: str | None = None,
    origin: tuple[float, float] | None = None,
    compress: str = "deflate",
    cog: bool = False,
    workers: int | None = None,
    block: int = 2048,
    progress: bool | None = None,
) -> Path:
    """Write ``FractalHeights`` of rows × cols cells as a tiled, compressed GeoTIFF (or COG).

    Blocks of ``block`` × ``block`` cells are computed by dask threads and written by one writer,
    so memory stays at a few blocks whatever the size. Square cells of ``cell_size`` map units;
    origin: (x, y) of the north-west corner [default (0, rows × cell_size): the south-west
    corner at (0, 0)]. Written beside ``path`` and renamed into place, tagged as approxtree's
    (``own_output.GEOTIFF_TAG``); refused before the first block when the disk lacks the room.
    Returns the path.
    """
    from approxtree.io.own_output import GEOTIFF_TAG
    from approxtree.io.tiled_geotiff import write_tiled_geotiff

    cols = rows if cols is None else cols
    source = FractalHeights(
        (rows, cols), seed=seed, hurst=hurst, relief=relief, wavelength=wavelength, holes=holes
    )
    if not (math.isfinite(cell_size) and cell_size > 0):
        raise InvalidParameterError(f"cell_size must be a positive length, got {cell_size}.")
    x0, y0 = (0.0, rows * cell_size) if origin is None else origin
    transform = Affine(cell_size, 0.0, x0, 0.0, -cell_size, y0)
    return write_tiled_geotiff(
        path,
        source,
        transform,
        crs=crs,
        nodata=source.nodata,
        compress=compress,
        cog=cog,
        workers=workers,
        block=block,
        progress=progress,
        tags={GEOTIFF_TAG: "fractal"},
    )


def _meander(rng: np.random.Generator, start: np.ndarray, steps: int, step: float) -> np.ndarray:
    """A random meandering polyline: (steps + 1, 2) points with smoothly turning heading."""
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0.0, 0.25, steps))
    moves = step * np.column_stack([np.cos(heading), np.sin(heading)])
    return np.vstack([start, start + np.cumsum(moves, axis=0)])


def river_pieces(grid: Grid, count: int, seed: int = 0, step: float | None = None) -> np.ndarray:
    """At least ``count`` short river pieces inside ``grid``'s domain: random meandering rivers
    of 40 steps of ``step`` world units (default: the grid's cell size), cut into pieces of two
    steps, each piece one microstructure's centre line. Returns a shapely LineString array."""
    import shapely

    step = float(grid.cell_size[0]) if step is None else float(step)
    rng = np.random.default_rng(seed)
    d = grid.domain
    inner = shapely.box(d.xmin, d.ymin, d.xmax, d.ymax).buffer(-step)
    # A piece that leaves the domain's inner box is dropped: its corridor would be cut.
    pieces_per_river = 20
    lines: list = []
    while len(lines) < count:
        start = rng.uniform([d.xmin, d.ymin], [d.xmax, d.ymax])
        path = _meander(rng, start, 2 * pieces_per_river, step)
        pieces = [shapely.linestrings(path[2 * k : 2 * k + 3]) for k in range(pieces_per_river)]
        lines.extend(p for p in pieces if inner.contains(p))
    return np.array(lines, dtype=object)


def case_study_terrain(
    seed: int = 0,
    rows: int = 321,
    cols: int = 641,
    microstructures: int = 20_652,
    cell_size: float = 30.0,
    width: float = 1.3,
    spacing: float = 1.1,
):
    """The scale of the core paper's cartographic case study, made synthetically.

    A fractal grid of rows × cols points plus ``microstructures`` river-bed TINs (incised
    corridors along random meandering rivers, each river cut into pieces of one microstructure
    each); width and spacing of the corridors are in cells. Returns (grid, list of TINs);
    with the defaults the full model has about 500,000
    triangles, as in the paper (641 × 321 grid, 20,652 microstructures).
    """
    from approxtree.io.microstructures import corridor_microstructures

    grid = fractal_terrain(rows, cols, seed=seed, relief=600.0, cell_size=cell_size)
    # A few spare pieces make up for the ones that end up with no triangle of their own
    # (crossed by a nearer river).
    lines = river_pieces(grid, int(np.ceil(microstructures * 1.04)), seed, cell_size)
    tins = corridor_microstructures(
        grid,
        lines,
        width=width * cell_size,
        spacing=spacing * cell_size,
        profile="incised",
        depth=3.0,
    )
    if len(tins) < microstructures:
        raise RuntimeError(f"only {len(tins)} microstructures could be made")  # pragma: no cover
    return grid, tins[:microstructures]
