"""GridPatch: the regular-grid strategy (core paper, section 3.2).

The patch keeps every sr-th row and every sc-th column of the shared Grid inside its rectangle
(plus the last ones, so it covers the rectangle exactly). Only the index range and the two
steps are stored; vertices are read from the grid on demand. With s = k² max points the steps
are the smallest that keep at most k lines per direction.
"""

from __future__ import annotations

import gc
import math
from collections.abc import Sequence

import numba
import numpy as np

from approxtree.errors import UnsupportedStrategyError
from approxtree.geometry.base import GeometryData
from approxtree.geometry.grid import Grid
from approxtree.geometry.rect import Rect
from approxtree.geometry.windowed import WindowedHeights, check_whole_band
from approxtree.kernels._jit import readonly
from approxtree.kernels.grid_patch import grid_patch_errors, grid_patch_mesh
from approxtree.kernels.row_column import coarsest_uniform_step, lattice_error
from approxtree.patches.base import GeometryPatch
from approxtree.patches.records import Batch, gather


def grid_steps(n_lines: int, max_lines: int) -> int:
    """Smallest step keeping at most ``max_lines`` sampled lines out of ``n_lines`` (>= 2)."""
    return max(1, math.ceil((n_lines - 1) / (max_lines - 1)))


def lattice_world_mesh(
    grid: Grid,
    rows: np.ndarray,
    cols: np.ndarray,
    tris: np.ndarray,
    z: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """World vertices (n, 3) float64 and CCW triangles (m, 3) of the rows × cols sub-lattice.

    rows, cols: grid row and column indices kept; tris: (m, 3) indices into the row-major
    rows × cols vertices, orient > 0 in (column, row) index space; z: the (rows, cols) heights
    when already read (else read from the grid). Nodata vertices are left out together with the
    triangles touching them.
    """
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    if z is None:
        z = grid.heights[rr, cc]
    verts = np.column_stack(
        [grid.x_coords[cc.ravel()], grid.y_coords[rr.ravel()], np.asarray(z).ravel()]
    ).astype(np.float64)
    # Index space is (col, row); a north-up transform mirrors it, so flip to stay CCW.
    if grid.transform.a * grid.transform.e < 0:
        tris = tris[:, [0, 2, 1]]
    # Drop nodata vertices and renumber the triangles over the remaining ones.
    keep = np.isfinite(verts[:, 2])
    if not keep.all():
        new_index = np.cumsum(keep) - 1
        verts = verts[keep]
        tris = new_index[tris]
    return verts, np.ascontiguousarray(tris)


class GridPatch(GeometryPatch):
    """Regular rows and columns of a Grid: stores (r0, r1, c0, c1) and the steps (sr, sc)."""

    kind = "grid"

    #: D_N, or None until made from ``_box`` on first access (patches made from a level's
    #: arrays: ``from_arrays``, ``GridPatchArrays.patch``).
    _rect: Rect | None
    #: (xmin, ymin, xmax, ymax) of D_N, set with ``_rect = None``.
    _box: list[float]

    def __init__(
        self,
        grid: Grid,
        rect: Rect,
        index: tuple[int, int, int, int, int, int],
        error: float,
        z_range: tuple[float, float],
        data_count: int,
    ) -> None:
        self.grid = grid
        self.rect = rect
        self.index = tuple(int(v) for v in index)
        self.error = float(error)
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.data_count = int(data_count)
        self._mesh: tuple[np.ndarray, np.ndarray] | None = None
        #: (kr, kc) heights of the sampled lattice when the record carried them (coarse patches).
        self._lattice_z: np.ndarray | None = None

    @staticmethod
    def _require_grid(terrain: GeometryData) -> Grid:
        # A GridRefinement's grid patches sample its base grid (errors re-measured on build).
        terrain = getattr(terrain, "grid", terrain)
        if not isinstance(terrain, Grid):
            raise UnsupportedStrategyError(
                f"The grid strategy needs a regular Grid, got a {type(terrain).__name__}; "
                "choose a strategy made for this data type."
            )
        return terrain

    @classmethod
    def build_many(
        cls,
        terrain: GeometryData,
        rects: Sequence[Rect],
        max_points: int,
        epsilon: float = 0.0,
    ) -> list[GridPatch]:
        boxes = np.array([r.as_tuple() for r in rects], dtype=np.float64).reshape(-1, 4)
        patches = cls.build_level(terrain, boxes, max_points, epsilon)
        for p, rect in zip(patches, rects, strict=True):
            p.__dict__["_rect"] = rect
        return patches

    @classmethod
    def build_level(
        cls,
        terrain: GeometryData,
        rects: np.ndarray,
        max_points: int,
        epsilon: float = 0.0,
    ) -> list[GridPatch]:
        grid = cls._require_grid(terrain)
        patches = cls.build_level_arrays(grid, rects, max_points).patches()
        if terrain is not grid:
            from approxtree.patches.refined import refine_grid_patches

            refine_grid_patches(terrain, patches)
        return patches

    # The base class cannot name GridPatchArrays (it would import this module): the table
    # widens its return type, and the tree's builder tells the two apart with isinstance.
    @classmethod
    def build_level_table(  # type: ignore[override]
        cls,
        terrain: GeometryData,
        rects: np.ndarray,
        max_points: int,
        epsilon: float = 0.0,
    ) -> Sequence[GeometryPatch] | GridPatchArrays:
        # A refined grid re-measures its patches: objects; a plain grid keeps arrays.
        grid = cls._require_grid(terrain)
        if terrain is not grid:
            return cls.build_level(terrain, rects, max_points, epsilon)
        return cls.build_level_arrays(grid, rects, max_points)

    @classmethod
    def build_level_arrays(cls, grid: Grid, rects: np.ndarray, max_points: int) -> GridPatchArrays:
        """The grid patches of a level's (k, 4) float64 rectangles over ``grid``, as arrays
        (no object per node: ``GridPatchArrays.patch`` makes one on demand)."""
        # The steps depend on s alone: a regular grid cannot stop early at epsilon.
        k = math.isqrt(max_points)
        ranges = grid.index_ranges(rects)
        # grid_steps of every range at once: ceil((lines − 1) / (k − 1)), at least 1.
        spans = np.column_stack([ranges[:, 1] - ranges[:, 0], ranges[:, 3] - ranges[:, 2]])
        steps = np.maximum(1, -(-spans // (k - 1))).astype(np.int64)
        heights = grid.heights_array("building grid patches")
        # No more threads than nodes on a small level: an idle thread still costs a hand-off
        # per call, which dominates when a small subtree (a block of a blocked build) is built
        # level by level. A large one is cut into bands of rows by the kernel: all threads.
        threads = numba.get_num_threads()
        points = int(np.sum((ranges[:, 1] - ranges[:, 0] + 1) * (ranges[:, 3] - ranges[:, 2] + 1)))
        work = len(ranges) if points < 1 << 18 else threads
        numba.set_num_threads(max(1, min(threads, work)))
        try:
            error, zmin, zmax, count = grid_patch_errors(readonly(heights), ranges, steps)
        finally:
            numba.set_num_threads(threads)
        index = np.column_stack([ranges, steps])
        rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
        return GridPatchArrays(grid, rects, index, error, zmin, zmax, count)

    @classmethod
    def from_arrays(
        cls,
        grid: Grid,
        rects: np.ndarray,
        index: np.ndarray,
        error: np.ndarray,
        zmin: np.ndarray,
        zmax: np.ndarray,
        count: np.ndarray,
    ) -> list[GridPatch]:
        """The patches of k nodes from their arrays: rects (k, 4), index (k, 6) (r0, r1, c0,
        c1, sr, sc), error, zmin, zmax, count (k,). Equal to calling the constructor per node;
        the objects are filled directly (a level of a tree holds up to millions)."""
        new = object.__new__
        out: list[GridPatch] = []
        append = out.append
        # Millions of new objects, none cyclic: the cyclic collector would rescan all of them
        # many times over (most of the time spent here without this).
        collecting = gc.isenabled()
        gc.disable()
        try:
            columns = (
                np.asarray(rects, dtype=np.float64).tolist(),
                np.asarray(index, dtype=np.int64).tolist(),
                np.asarray(error, dtype=np.float64).tolist(),
                np.asarray(zmin, dtype=np.float64).tolist(),
                np.asarray(zmax, dtype=np.float64).tolist(),
                np.asarray(count, dtype=np.int64).tolist(),
            )
            for box, idx, e, lo, hi, n in zip(*columns, strict=True):
                p = new(cls)
                p.__dict__.update(
                    grid=grid,
                    _rect=None,
                    _box=box,
                    index=tuple(idx),
                    error=e,
                    z_range=(lo, hi),
                    data_count=n,
                    _mesh=None,
                    _lattice_z=None,
                )
                append(p)
        finally:
            if collecting:
                gc.enable()
        return out

    @property
    def rect(self) -> Rect:
        """D_N (made from the level's array row on first access)."""
        r = self._rect
        if r is None:
            r = self._rect = Rect(*self._box)
        return r

    @rect.setter
    def rect(self, value: Rect) -> None:
        self._rect = value

    @classmethod
    def approximate(
        cls,
        terrain: GeometryData,
        max_error: float | None,
        max_points: int | None,
        max_triangles: int | None,
        data_dependent: bool = False,
    ) -> GeometryPatch:
        return approximate_grid(terrain, max_error, max_points, max_triangles)

    @property
    def steps(self) -> tuple[int, int]:
        return self.index[4], self.index[5]

    @property
    def is_full_resolution(self) -> bool:
        """True when every data line of the rectangle is sampled (the patch equals T there)."""
        return self.steps == (1, 1)

    @property
    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        """Sampled rows (kr,) and columns (kc,) int64: every step-th line and the last one."""
        r0, r1, c0, c1, sr, sc = self.index
        rows = np.append(np.arange(r0, r1, sr), r1).astype(np.int64)
        cols = np.append(np.arange(c0, c1, sc), c1).astype(np.int64)
        return rows, cols

    @property
    def rms_error(self) -> float:
        """Exact RMS of ``|h_T − h_TN|`` over the rectangle's valid data points (measured on
        demand)."""
        rows, cols = self.lines
        heights = self.grid.heights
        if isinstance(heights, WindowedHeights):
            # Only the patch's own window is read (the error needs every data point in it).
            r0, r1, c0, c1 = self.index[:4]
            check_whole_band((r1 - r0 + 1, c1 - c0 + 1), heights.dtype, "GridPatch.rms_error")
            z = heights[r0 : r1 + 1, c0 : c1 + 1]
            _, sumsq, count, _, _ = lattice_error(readonly(z), rows - r0, cols - c0)
        else:
            _, sumsq, count, _, _ = lattice_error(readonly(heights), rows, cols)
        return float(np.sqrt(sumsq / max(count, 1)))

    @property
    def stores_lattice(self) -> bool:
        """True when the patch's record carries its lattice heights (see LATTICE_STORED_STEP)."""
        return max(self.steps) >= LATTICE_STORED_STEP

    def lattice_heights(self) -> np.ndarray:
        """(kr, kc) heights at the sampled rows × columns (NaN for nodata)."""
        if self._lattice_z is not None:
            return self._lattice_z
        rows, cols = self.lines
        return np.asarray(self.grid.heights[rows[:, None], cols[None, :]])

    def _build_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        g = self.grid
        r0, r1, c0, c1, sr, sc = self.index
        if isinstance(g.heights, WindowedHeights) or self._lattice_z is not None:
            # Only the sampled lattice is read (or it came with the record); the kernel sees
            # it with steps 1.
            rows, cols = self.lines
            z = self.lattice_heights()
            _, _, tris = grid_patch_mesh(readonly(z), 0, len(rows) - 1, 0, len(cols) - 1, 1, 1)
            return lattice_world_mesh(g, rows, cols, tris, z)
        rows, cols, tris = grid_patch_mesh(readonly(g.heights), r0, r1, c0, c1, sr, sc)
        return lattice_world_mesh(g, rows, cols, tris)

    @property
    def vertices(self) -> np.ndarray:
        if self._mesh is None:
            self._mesh = self._build_mesh()
        return self._mesh[0]

    @property
    def triangles(self) -> np.ndarray:
        if self._mesh is None:
            self._mesh = self._build_mesh()
        return self._mesh[1]

    @property
    def point_count(self) -> int:
        r0, r1, c0, c1, sr, sc = self.index
        return ((r1 - r0 + sr - 1) // sr + 1) * ((c1 - c0 + sc - 1) // sc + 1)

    @property
    def nbytes(self) -> int:
        return 6 * 8

    def to_record(self) -> dict[str, np.ndarray]:
        # Records hold the full raster's indices, whether the patch was built on it or a window.
        r_off, c_off = self.grid.index_offset
        r0, r1, c0, c1, sr, sc = self.index
        index = (r0 + r_off, r1 + r_off, c0 + c_off, c1 + c_off, sr, sc)
        z = self.lattice_heights().reshape(-1) if self.stores_lattice else np.empty(0)
        return {
            "index": np.array(index, dtype="<i8"),
            "stats": np.array([self.error, *self.z_range, self.data_count], dtype="<f8"),
            "z": z.astype("<f8"),
        }

    @classmethod
    def records_many(cls, patches: Sequence[GridPatch]) -> Batch:
        # Fixed-width records: one (k, 6) and one (k, 4) table gathered from the attributes.
        ps = list(patches)
        k = len(ps)
        stats = ((p.error, *p.z_range, p.data_count) for p in ps)
        index = gather((p.index for p in ps), k, 6, "<i8")
        # Records hold the full raster's indices (as to_record), whatever window a patch is on.
        offsets = np.array([p.grid.index_offset for p in ps], dtype=np.int64).reshape(k, 2)
        index[0].reshape(k, 6)[:, :4] += offsets.repeat(2, axis=1)
        # stores_lattice of every patch at once, from the steps just gathered.
        steps = index[0].reshape(k, 6)[:, 4:]
        coarse = np.flatnonzero(steps.max(axis=1, initial=0) >= LATTICE_STORED_STEP)
        return {
            "index": index,
            "stats": gather(stats, k, 4, "<f8"),
            "z": _lattices_many(k, {i: ps[i] for i in coarse.tolist()}),
        }

    @classmethod
    def from_record(
        cls, terrain: GeometryData, rect: Rect, record: dict[str, np.ndarray]
    ) -> GridPatch:
        grid = cls._require_grid(terrain)
        r0, r1, c0, c1, sr, sc = (int(v) for v in record["index"])
        r_off, c_off = grid.index_offset
        index = (r0 - r_off, r1 - r_off, c0 - c_off, c1 - c_off, sr, sc)
        error, zmin, zmax, count = (float(v) for v in record["stats"])
        patch = cls(grid, rect, index, error, (zmin, zmax), int(count))
        z = record.get("z")
        if z is not None and len(z):
            rows, cols = patch.lines
            patch._lattice_z = np.asarray(z, dtype=np.float64).reshape(len(rows), len(cols))
        return patch


#: Coarsest steps from which a grid patch's record carries its lattice heights: the lattice of
#: a coarse patch touches a chunk of the stored terrain per vertex, so reading it back from the
#: terrain would decode most of the raster (4.5 s for the root of a 32768² tree); stored, it is
#: 8 bytes a vertex (coarse patches are few: about 1/256 of the nodes of a quadtree).
LATTICE_STORED_STEP = 16


def _lattices_many(k: int, coarse: dict[int, GridPatch]) -> tuple[np.ndarray, np.ndarray]:
    """(flat, offsets) of the lattice heights of k records: those of the patches that store
    them, none for the others.

    coarse: the patches that store their lattice by their position among the k, ascending.
    All lattices over one grid are read with one index gather, so a windowed grid reads each of
    its blocks once, however many coarse patches cover it.
    """
    sizes = np.zeros(k, dtype=np.int64)
    flat = np.empty(0, dtype="<f8")
    if coarse:
        pieces: dict[int, np.ndarray] = {
            i: np.asarray(p._lattice_z, dtype="<f8").reshape(-1)
            for i, p in coarse.items()
            if p._lattice_z is not None
        }
        parts: dict[int, list[int]] = {}
        for i, p in coarse.items():
            if i not in pieces:
                parts.setdefault(id(p.grid), []).append(i)
        for members in parts.values():
            lines = [coarse[i].lines for i in members]
            rr = np.concatenate([np.repeat(r, len(c)) for r, c in lines])
            cc = np.concatenate([np.tile(c, len(r)) for r, c in lines])
            z = np.asarray(coarse[members[0]].grid.heights[rr, cc], dtype="<f8")
            ends = np.cumsum([len(r) * len(c) for r, c in lines])
            for i, part in zip(members, np.split(z, ends[:-1]), strict=True):
                pieces[i] = part
        for i in coarse:
            sizes[i] = len(pieces[i])
        flat = np.concatenate([pieces[i] for i in coarse])
    offsets = np.zeros(k + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    return flat, offsets


class GridPatchArrays:
    """The grid patches of k nodes as arrays (a level of a build): Python runs per level, and
    a node's GridPatch is made only when asked for (``patch``).

    rects: (k, 4) float64 D_N; index: (k, 6) int64 (r0, r1, c0, c1, sr, sc) over ``grid``;
    error, zmin, zmax: (k,) float64; count: (k,) int64 valid data points.
    """

    kind = GridPatch.kind

    def __init__(
        self,
        grid: Grid,
        rects: np.ndarray,
        index: np.ndarray,
        error: np.ndarray,
        zmin: np.ndarray,
        zmax: np.ndarray,
        count: np.ndarray,
    ) -> None:
        self.grid = grid
        self.rects = rects
        self.index = index
        self.error = error
        self.zmin = zmin
        self.zmax = zmax
        self.count = count

    def __len__(self) -> int:
        return len(self.error)

    @classmethod
    def concat(cls, parts: Sequence[GridPatchArrays]) -> GridPatchArrays:
        """One table of the rows of ``parts`` (all over the same grid), in order."""
        grids = {id(p.grid) for p in parts}
        if len(grids) != 1:
            raise ValueError("GridPatchArrays.concat needs parts over one grid")
        return cls(
            parts[0].grid,
            *(np.concatenate([getattr(p, f) for p in parts]) for f in cls._fields),
        )

    _fields = ("rects", "index", "error", "zmin", "zmax", "count")

    def patch(self, i: int) -> GridPatch:
        """Row i's GridPatch (equal to the one ``patches`` makes)."""
        p = object.__new__(GridPatch)
        p.__dict__.update(
            grid=self.grid,
            _rect=None,
            _box=self.rects[i].tolist(),
            index=tuple(self.index[i].tolist()),
            error=float(self.error[i]),
            z_range=(float(self.zmin[i]), float(self.zmax[i])),
            data_count=int(self.count[i]),
            _mesh=None,
            _lattice_z=None,
        )
        return p

    def patches(self, rows: np.ndarray | None = None) -> list[GridPatch]:
        """The GridPatch of every row (or of ``rows``), in order."""
        cols = [getattr(self, f) for f in self._fields]
        if rows is not None:
            cols = [c[rows] for c in cols]
        return GridPatch.from_arrays(self.grid, *cols)

    def coarse(self, rows: np.ndarray | None = None) -> np.ndarray:
        """(j,) int64 positions in ``rows`` (default: every row) of the patches whose records
        carry their lattice heights (``stores_lattice``)."""
        steps = self.index[:, 4:] if rows is None else self.index[rows, 4:]
        return np.flatnonzero(steps.max(axis=1, initial=0) >= LATTICE_STORED_STEP)

    def records(self, rows: np.ndarray, lattices: Sequence[GridPatch]) -> Batch:
        """The batch of records of ``rows`` (k,), equal to ``GridPatch.records_many`` of their
        patches; ``lattices``: the patches of the rows among them that store their lattice
        (``coarse``), in the same order (their heights are read through them)."""
        rows = np.asarray(rows, dtype=np.int64)
        k = len(rows)
        index = np.array(self.index[rows], dtype="<i8")
        # Records hold the full raster's indices (as GridPatch.to_record).
        index[:, :4] += np.array(self.grid.index_offset, dtype=np.int64).repeat(2)
        index = index.reshape(-1)
        stats = np.empty((k, 4), dtype="<f8")
        stats[:, 0] = self.error[rows]
        stats[:, 1] = self.zmin[rows]
        stats[:, 2] = self.zmax[rows]
        stats[:, 3] = self.count[rows]
        at = self.coarse(rows)
        held = dict(zip(at.tolist(), lattices, strict=True))
        width = np.arange(k + 1, dtype=np.int64)
        return {
            "index": (index, width * 6),
            "stats": (stats.reshape(-1), width * 4),
            "z": _lattices_many(k, held),
        }


def _uniform_counts(rows: int, cols: int, step: int) -> tuple[int, int]:
    """(lattice points, triangles) of a whole-grid patch with the same step in both directions."""
    nbr = (rows - 1 + step - 1) // step
    nbc = (cols - 1 + step - 1) // step
    return (nbr + 1) * (nbc + 1), 2 * nbr * nbc


def uniform_step(
    grid: Grid,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
) -> int:
    """The step of the uniform regular grid over the whole terrain meeting the goal.

    A point or triangle budget: the smallest step whose lattice fits it. An error goal: the
    largest step whose exact error is at most ``max_error`` (errors are not monotone in the
    step, so every step is tried; the point count still falls as ``max_error`` grows, because
    a larger goal admits every step a smaller one does).
    """
    rows, cols = grid.shape
    longest = max(rows, cols) - 1
    if max_error is None:
        for step in range(1, longest + 1):
            points, tris = _uniform_counts(rows, cols, step)
            if (max_points is None or points <= max_points) and (
                max_triangles is None or tris <= max_triangles
            ):
                return step
        return longest
    z = grid.heights_array("the uniform grid approximation")
    return int(coarsest_uniform_step(readonly(z), float(max_error)))


def approximate_grid(
    terrain: GeometryData,
    max_error: float | None,
    max_points: int | None,
    max_triangles: int | None,
) -> GridPatch:
    """The uniform regular grid of a whole terrain (see ``patches.approximate``)."""
    grid = GridPatch._require_grid(terrain)
    step = uniform_step(grid, max_error, max_points, max_triangles)
    rows, cols = grid.shape
    index = np.array([[0, rows - 1, 0, cols - 1]], dtype=np.int64)
    error, zmin, zmax, count = grid_patch_errors(
        readonly(grid.heights_array("the uniform grid approximation")),
        index,
        np.array([[step, step]], dtype=np.int64),
    )
    return GridPatch(
        grid,
        grid.domain,
        (0, rows - 1, 0, cols - 1, step, step),
        error[0],
        (zmin[0], zmax[0]),
        count[0],
    )
