"""One tile's TIN, within its error at the terrain's data points as CesiumJS decodes the tile.

1. Candidates (``tile_mesh``): the terrain's data points in the tile (``data_points``) at
   their (u, v) rounded to the quantized grid (a point strictly inside the tile never onto
   its edge; a point on the grid's outer edge outward, so that its true position lies on the
   terrain's side of its vertex); the tile's sample lattice (``sampling``) where it says what
   the data points do not: its edges (shared with the neighbours), outside the terrain (the
   edge carried outward, then FILL_HEIGHT) and nodata; and, beside every data point within
   about a cell of the tile's edge, a point on the edge (else the strip between them would
   interpolate the edge's sparse lattice samples). Lattice and edge heights are functions of
   the position, so neighbours agree on their shared edge; a lattice sample at a data point's
   position gives way to it, and of the points sharing a position one stands for all.
2. The scattered-point greedy insertion (``kernels.greedy_points``) inserts candidates until
   each is within a target that leaves room for the height quantization.
3. The mesh as CesiumJS decodes it (heights lerp(min, max, h / QMAX) between the header's
   float32 bounds, linear in (u, v) as QuantizedMeshTerrainData.interpolateHeight) is
   measured at every data point at its TRUE, unrounded (u, v), and at every lattice and edge
   candidate (``kernels.region_errors``): the tile's error is the largest at the data points.
4. Over the error: a candidate off by its rounding lowers the target just under its error
   where the insertion saw it (so it is inserted; at most halving it, MAX_TIGHTENINGS times);
   points that were not candidates (below) join them. Then again from 2. The error reported
   is the measured one whatever ends the rounds.

Bounded memory: a tile holding more than FIRST_CANDIDATES data points (coarse tiles hold a
whole DEM) starts from those on every k-th row and column; step 3 then measures every point,
chunk by chunk (MEASURE_CHUNK at a time); where many are over the error k is halved (while
at most POINT_CAP remain), else the worst VIOLATOR_CAP of them join the candidates, until
none is over or POINT_CAP have joined. A tile's peak memory is thus about 250 bytes per
candidate (the insertion's arrays) for at most 2 · POINT_CAP + samples² candidates (≈ 0.5 GB)
and 100 bytes per point of a chunk (0.1 GB), plus the block cache of ``data_points``
(LONLAT_CACHE_BYTES), whatever the size of the terrain.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from approxtree.kernels.greedy_points import greedy_point_tin
from approxtree.kernels.region_errors import region_point_errors
from approxtree.tiles.data_points import PointSet, TilePoints
from approxtree.tiles.encoding import QMAX, quantize_heights

#: The lattice's heights at (n,) quantized positions u, v on a tile's edges.
EdgeHeights = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Data points a tile's greedy insertion starts from at most (a tile holding more starts from
#: a stride-decimated subset, see the module): a small start is quicker than all of a coarse
#: tile's points, which its large error does not need.
FIRST_CANDIDATES = 1 << 16
#: Decimated candidates at most (the stride is halved while the count stays under it); the
#: bound on a tile's memory.
POINT_CAP = 1 << 20
#: Data points measured per kernel call on a decimated tile.
MEASURE_CHUNK = 1 << 20
#: Points over the error that join the candidates per round, at most (the worst first).
VIOLATOR_CAP = 1 << 16
#: Times the target is tightened at most (points over the error that were not candidates are
#: added until none is left, within POINT_CAP more candidates).
MAX_TIGHTENINGS = 12
#: Barycentric slack when locating a point, so points on shared edges are found.
_TOL = 1e-9


@dataclass
class TileMesh:
    """A tile's decoded TIN: u, v (n,) int64 quantized positions, triangles (m, 3) int64
    counter-clockwise, hq (n,) int64 quantized heights, decoded (n,) float64 the heights they
    decode to; error: the true max |TIN − h_T| over the tile's data points (0 without any);
    data_points: how many were measured; rounds: insertions run."""

    u: np.ndarray
    v: np.ndarray
    triangles: np.ndarray
    hq: np.ndarray
    decoded: np.ndarray
    error: float
    data_points: int
    rounds: int


def _rounded(points: PointSet) -> tuple[np.ndarray, np.ndarray]:
    """Quantized positions du, dv (n,) float64 of the points: the nearest integers, except
    that a point on the grid's outer edge rounds outward along each axis its outward step
    mostly follows (so its true position lies inward of its vertex, not on the drop beyond
    the terrain), and a point strictly inside the tile never rounds onto its edge."""
    out = []
    norm = np.hypot(points.ou, points.ov)
    for q, dq in ((points.u, points.ou), (points.v, points.ov)):
        r = np.rint(q)
        along = np.abs(dq) >= 0.25 * norm
        r = np.where(along & (dq > 0), np.ceil(q), np.where(along & (dq < 0), np.floor(q), r))
        inner = (q > 0.0) & (q < QMAX)
        out.append(np.where(inner, np.clip(r, 1.0, QMAX - 1.0), np.clip(r, 0.0, QMAX)))
    return out[0], out[1]


def _edge_candidates(
    data: PointSet, k: int, edge_heights: EdgeHeights, reach: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, h) float64: points on the tile's edges beside the data points less than
    ``reach`` (about a cell, in quantized steps) inside them: without them the strip between
    the last data points and the edge would interpolate the edge's lattice samples, which may
    lie far apart along it. Positions on the lattice are left out (the lattice has them); h is
    a function of the position (``TileSampler.heights_at``), so the neighbour agrees."""
    parts = []
    reach = max(reach, 1.0)
    for q, other, edge in ((data.u, data.v, 0.0), (data.v, data.u, 1.0)):
        along = np.clip(np.rint(other), 0.0, QMAX)
        for side, near in (
            (0.0, (q > 0.0) & (q < reach)),
            (QMAX, (q > QMAX - reach) & (q < QMAX)),
        ):
            pos = np.unique(along[near])
            pos = pos[pos % k != 0]
            fixed = np.full(len(pos), side)
            parts.append((fixed, pos) if edge == 0.0 else (pos, fixed))
    eu = np.concatenate([p[0] for p in parts])
    ev = np.concatenate([p[1] for p in parts])
    if not len(eu):
        return eu, ev, np.empty(0)
    h = edge_heights(eu, ev)
    ok = np.isfinite(h)
    return eu[ok], ev[ok], h[ok]


def _lattice_kept(du: np.ndarray, dv: np.ndarray, s: int, k: int) -> np.ndarray:
    """(s², ) bool: the lattice samples (row-major from the south-west, spacing k) that no
    data point's rounded position (du, dv) falls on."""
    keep = np.ones(s * s, dtype=bool)
    on = (du % k == 0) & (dv % k == 0)
    if on.any():
        keep[(dv[on] // k).astype(np.int64) * s + (du[on] // k).astype(np.int64)] = False
    return keep


def _one_per_position(du: np.ndarray, dv: np.ndarray, z: np.ndarray) -> np.ndarray | None:
    """Indices of one point per rounded position (n,) (the one whose height is nearest the
    mid-range of the heights there: a vertex there is then off by the least at the others),
    or None when no two points share a position. Points sharing a vertex's position keep
    their errors whatever is inserted, and the insertion would only rescan them."""
    if len(du) < 2:
        return None
    key = du.astype(np.int64) * (QMAX + 1) + dv.astype(np.int64)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.concatenate([[True], ks[1:] != ks[:-1]]))
    if len(starts) == len(key):
        return None
    zs = z[order]
    mid = 0.5 * (np.minimum.reduceat(zs, starts) + np.maximum.reduceat(zs, starts))
    group = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, len(ks))))
    best = np.lexsort((np.abs(zs - mid[group]), group))
    first = best[np.concatenate([[True], group[best][1:] != group[best][:-1]])]
    return np.sort(order[first])


def _greedy_target(z: np.ndarray, max_error: float) -> float:
    """The insertion's target: room for the height quantization (a decoded vertex is off by at
    most half a step, a triangle's plane by at most its corners' largest offset)."""
    lo, hi = float(z.min()), float(z.max())
    room = (hi - lo) / (2 * QMAX) * (1.0 + 1e-9) + 1e-9 * max(abs(lo), abs(hi))
    return max(max_error - room, 0.0)


class _Mesh:
    """The decoded mesh of one insertion: vertices' (u, v), decoded heights, triangles."""

    def __init__(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, target: float) -> None:
        verts, tv, _, _ = greedy_point_tin(x, y, z, target, 0)
        self.triangles = tv.reshape(-1, 3).astype(np.int64)
        self.u, self.v = x[verts], y[verts]
        self.heights = z[verts]
        self.hq, self.decoded, _, _ = quantize_heights(self.heights)

    def errors(
        self, pts_u: np.ndarray, pts_v: np.ndarray, pts_z: np.ndarray, decoded: bool = True
    ) -> np.ndarray:
        """(n,) |z − mesh| at (n,) points (inf for one outside every triangle): the mesh as
        decoded, or (``decoded=False``) with the vertices' own heights, as the insertion saw it."""
        vz = self.decoded if decoded else self.heights
        return region_point_errors(self.u, self.v, vz, self.triangles, pts_u, pts_v, pts_z, _TOL)


class _Worst:
    """The worst points over the error among those measured so far, at most VIOLATOR_CAP."""

    def __init__(self) -> None:
        self.points, self.errors = PointSet.empty(), np.empty(0)

    def add(self, points: PointSet, errors: np.ndarray) -> None:
        self.points = PointSet.concat([self.points, points])
        self.errors = np.concatenate([self.errors, errors])
        if len(self.errors) > VIOLATOR_CAP:
            top = np.argpartition(self.errors, -VIOLATOR_CAP)[-VIOLATOR_CAP:]
            self.points, self.errors = self.points.take(top), self.errors[top]


@dataclass
class _Measure:
    """Step 3: the worst error over the data points, how many were measured, the worst of
    those over the error that were candidates (``over``) and that were not (``fresh``), and
    how many of the latter there were."""

    worst: float
    count: int
    over: PointSet
    fresh: PointSet
    fresh_count: int = 0


def _measure(
    points: TilePoints,
    data: PointSet,
    mesh: _Mesh,
    max_error: float,
    stride: int,
    known: np.ndarray,
) -> _Measure:
    """Every data point of the tile measured: the candidates ``data`` when they are all of
    them (stride 1), else every point read again chunk by chunk (``known``: sorted cells of
    the candidates added so far)."""
    worst, count = 0.0, 0
    over, fresh = _Worst(), _Worst()
    fresh_count = 0
    chunks = [data] if stride == 1 else points.chunks(MEASURE_CHUNK)
    cols = points.blocks.cols
    for chunk in chunks:
        err = mesh.errors(chunk.u, chunk.v, chunk.z)
        count += len(err)
        worst = max(worst, float(err.max(initial=0.0)))
        bad = np.flatnonzero(err > max_error)
        if not len(bad):
            continue
        row, col = np.divmod(chunk.cell[bad], cols)
        was = (row % stride == 0) & (col % stride == 0) | np.isin(chunk.cell[bad], known)
        over.add(chunk.take(bad[was]), err[bad[was]])
        fresh.add(chunk.take(bad[~was]), err[bad[~was]])
        fresh_count += int((~was).sum())
    return _Measure(worst, count, over.points, fresh.points, fresh_count)


def _tightened(target: float, mesh: _Mesh, over: PointSet) -> float | None:
    """The target under which the insertion takes every candidate in ``over`` that is not a
    vertex yet (each is off at its true position by its rounding: inserted, it is exact at its
    vertex); None when all of them are vertices already (nothing a target changes)."""
    ru, rv = _rounded(over)
    keys = ru.astype(np.int64) * (QMAX + 1) + rv.astype(np.int64)
    vertex = mesh.u.astype(np.int64) * (QMAX + 1) + mesh.v.astype(np.int64)
    free = ~np.isin(keys, vertex)
    if not free.any():
        return None
    # Their errors where the insertion saw them (rounded, vertices' own heights): <= target,
    # unless another point there stood for them (a shared position).
    seen = mesh.errors(ru[free], rv[free], over.z[free], decoded=False)
    seen = seen[seen <= target]
    if not len(seen):
        return None
    # At most halved a round: a point far closer at its vertex than where it is (off by its
    # rounding on a steep slope) is not worth every other point of the tile.
    return max(float(seen.min()) * (1.0 - 1e-6) - 1e-12, 0.5 * target)


def _candidates(points: TilePoints, budget: int) -> tuple[PointSet, int]:
    """The tile's data points, or on a tile holding more than ``budget`` of them those on
    every k-th row and column; and k."""
    estimate = points.estimate()
    stride = 1 if estimate <= budget else math.ceil(math.sqrt(estimate / budget))
    cand = points.gather(stride)
    # The estimate is a block-box share: decimate further when it fell short.
    while len(cand) > 2 * budget:
        stride = math.ceil(stride * math.sqrt(len(cand) / budget))
        cand = points.gather(stride)
    return cand, stride


def tile_mesh(
    h: np.ndarray,
    measured: np.ndarray,
    points: TilePoints,
    edge_heights: EdgeHeights,
    edge_reach: float,
    max_error: float,
) -> TileMesh:
    """The TIN of one tile within ``max_error`` at its data points (see the module).

    h: (s, s) float64 lattice heights, row 0 south, column 0 west ((s − 1) divides QMAX);
    measured: (s, s) bool, where h is h_T inside the domain; points: the tile's data points;
    edge_heights: the lattice's heights at (n,) quantized positions on the tile's edges;
    edge_reach: how near (quantized steps) a data point is to an edge for one beside it.
    Returns its TileMesh.
    """
    s = h.shape[0]
    k = QMAX // (s - 1)
    jj, ii = np.divmod(np.arange(s * s, dtype=np.int64), s)
    lat_u, lat_v = (ii * k).astype(np.float64), (jj * k).astype(np.float64)
    lat_z = np.ascontiguousarray(h, dtype=np.float64).ravel()
    # Samples the data points do not stand for: the tile's edges, and where h is not h_T.
    lat_in = (ii == 0) | (ii == s - 1) | (jj == 0) | (jj == s - 1) | ~measured.ravel()
    cand, stride = _candidates(points, FIRST_CANDIDATES)
    extra, known = PointSet.empty(), np.empty(0, dtype=np.int64)
    target = None
    rounds = tightened = 0
    while True:
        rounds += 1
        data = PointSet.concat([cand, extra]) if len(extra) else cand
        du, dv = _rounded(data)
        keep = lat_in & _lattice_kept(du, dv, s, k)
        dz = data.z
        one = _one_per_position(du, dv, dz)
        if one is not None:
            du, dv, dz = du[one], dv[one], dz[one]
        eu, ev, ez = _edge_candidates(data, k, edge_heights, edge_reach)
        x = np.concatenate([lat_u[keep], eu, du])
        y = np.concatenate([lat_v[keep], ev, dv])
        z = np.concatenate([lat_z[keep], ez, dz])
        if target is None:
            target = _greedy_target(z, max_error)
        mesh = _Mesh(x, y, z, target)
        m = _measure(points, data, mesh, max_error, stride, known)
        # The samples are at exact positions (within the target and the quantization): this
        # is their measure, not an estimate.
        lattice = float(
            mesh.errors(
                np.concatenate([lat_u[keep], eu]),
                np.concatenate([lat_v[keep], ev]),
                np.concatenate([lat_z[keep], ez]),
            ).max()
        )
        if m.worst <= max_error and lattice <= max_error:
            break
        tighter = None
        if len(m.over) and tightened < MAX_TIGHTENINGS:
            tighter = _tightened(target, mesh, m.over)
        if tighter is None and not len(m.fresh):
            # Only vertices are over (by their rounding), or the target went as low as it
            # may: no insertion changes that.
            break
        if tighter is not None:
            target = tighter
            tightened += 1
        finer = max(stride // 2, 1)
        if m.fresh_count > len(data) // 64 and len(cand) * (stride / finer) ** 2 <= POINT_CAP:
            # Over in many places: the decimation misses detail everywhere, halve its stride
            # (the points added so far that are now on it are candidates anyway).
            stride = finer
            cand = points.gather(stride)
            row, col = np.divmod(extra.cell, points.blocks.cols)
            off = np.flatnonzero((row % stride != 0) | (col % stride != 0))
            extra = extra.take(off)
            known = np.unique(extra.cell)
        elif len(m.fresh):
            if len(extra) >= POINT_CAP:
                # The memory bound: the error reported is the measured one.
                break
            extra = PointSet.concat([extra, m.fresh])
            known = np.union1d(known, m.fresh.cell)
    return TileMesh(
        mesh.u.astype(np.int64),
        mesh.v.astype(np.int64),
        mesh.triangles,
        mesh.hq,
        mesh.decoded,
        m.worst,
        m.count,
        rounds,
    )
