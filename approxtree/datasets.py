"""Sample terrains: the real DEM shipped inside matplotlib, and seeded fractal terrain.

``sample_terrain()`` is the Jacksboro fault DEM (Tennessee, USGS 3″ data, 344 × 403) that ships
with matplotlib, so the demo needs no download. ``fractal_terrain()`` makes reproducible
fractional-Brownian surfaces of any size for benchmarks and scale tests.
"""

from __future__ import annotations

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

    No CRS: x and y are metres from the north-west corner at (0, rows × cell_size).
    """
    z = fractal_heights(rows, cols, seed=seed, hurst=hurst, relief=relief)
    transform = Affine(cell_size, 0.0, 0.0, 0.0, -cell_size, z.shape[0] * cell_size)
    return Grid(z, transform=transform)


def _meander(rng: np.random.Generator, start: np.ndarray, steps: int, step: float) -> np.ndarray:
    """A random meandering polyline: (steps + 1, 2) points with smoothly turning heading."""
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0.0, 0.25, steps))
    moves = step * np.column_stack([np.cos(heading), np.sin(heading)])
    return np.vstack([start, start + np.cumsum(moves, axis=0)])


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
    import shapely

    from approxtree.io.microstructures import corridor_microstructures

    grid = fractal_terrain(rows, cols, seed=seed, relief=600.0, cell_size=cell_size)
    rng = np.random.default_rng(seed)
    d = grid.domain
    inner = shapely.box(d.xmin, d.ymin, d.xmax, d.ymax).buffer(-cell_size)
    # Rivers of 40 steps of one cell, cut into pieces of two steps; each piece inside the
    # domain is one microstructure. A few spare pieces make up for the ones that end up with
    # no triangle of their own (crossed by a nearer river).
    pieces_per_river = 20
    lines: list = []
    while len(lines) < microstructures * 1.04:
        start = rng.uniform([d.xmin, d.ymin], [d.xmax, d.ymax])
        path = _meander(rng, start, 2 * pieces_per_river, cell_size)
        pieces = [shapely.linestrings(path[2 * k : 2 * k + 3]) for k in range(pieces_per_river)]
        lines.extend(p for p in pieces if inner.contains(p))
    tins = corridor_microstructures(
        grid,
        np.array(lines, dtype=object),
        width=width * cell_size,
        spacing=spacing * cell_size,
        profile="incised",
        depth=3.0,
    )
    if len(tins) < microstructures:
        raise RuntimeError(f"only {len(tins)} microstructures could be made")  # pragma: no cover
    return grid, tins[:microstructures]
