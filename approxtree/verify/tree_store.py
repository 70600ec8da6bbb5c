"""Verify a tree store (zarr v3 folder or zip) against its source terrain.

Read with zarr alone (``verify.zarr_read``), never with the store's own reader. Checks, in
order (a damaged store stops before the measurement, which would read fill values):

1. ``metadata``: the root's ``metadata_crc32c`` matches every group's and array's zarr.json
   (CRC-32C of the parsed document, keys sorted), and lists every member.
2. ``chunks``: every chunk of every array's chunk grid is on disk (zarr would read a missing
   one as its fill value); ``decode``: every chunk decodes (blosc, then the crc32c codec).
3. ``terrain``: the stored terrain is the source's (georeference, size, every height; for
   point sets the same points).
4. ``nodes``: the node table holds together (lengths, root, parents, levels, child ranges);
   ``partition``: each node's children partition its rectangle; ``patches``: every node has
   its patch (slot ↔ node both ways) and the record decodes.
5. ``errors``: each node's stored error is at least the true max |h_TN − h_T| over the source's
   data points in its closed rectangle (inf where a data point lies under no triangle or a
   nodata point under one, as the writers count it); ``epsilon``: leaves are within the tree's
   ε; ``bboxes``: B_N holds the patch's vertices and the data points.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from approxtree.verify.measure import measure_for
from approxtree.verify.report import VerifyReport, claims_hold
from approxtree.verify.tree_patches import PatchDecoder, UnsupportedTree
from approxtree.verify.zarr_read import (
    StoreFiles,
    chunk_selection,
    expected_chunk_keys,
    read_whole,
)

FORMAT = "approxtree-tree-store"
NODE_ARRAYS = (
    "rects",
    "errors",
    "bboxes",
    "levels",
    "parents",
    "child_start",
    "child_count",
    "strategies",
    "patch_slot",
)
#: Inside slack of the edge tests for the patches' exact vertices (cells or world units).
_TOL = 1e-9


def is_tree_store(files: StoreFiles) -> bool:
    return files.attrs.get("format") == FORMAT


def _metadata_crc(node: Any) -> int:
    import crc32c

    doc = json.dumps(node.metadata.to_dict(), sort_keys=True, default=str)
    return crc32c.crc32c(doc.encode())


def verify_tree_store(files: StoreFiles, terrain: Any, report: VerifyReport) -> None:
    """Run every check on the store ``files`` against the source ``terrain``."""
    meta = files.attrs.get("meta") or {}
    report.figures["tree_kind"] = meta.get("tree_kind")
    report.figures["terrain_kind"] = meta.get("terrain_kind")
    members = files.members()
    damaged = _check_metadata(files, members, report) | _check_chunks(files, members, report)
    if terrain is not None:
        _check_terrain(files, members, terrain, damaged, report)
    if meta.get("tree_kind") != "approximation_tree":
        report.not_checked.append(
            f"errors: a {meta.get('tree_kind')!r} tree holds no patches with claimed errors "
            "(its chunks, checksums and terrain are checked)"
        )
        return
    if damaged:
        report.not_checked.append(
            "node table, patches and errors: the store is damaged (see chunks/decode), so "
            f"they would be read from fill values ({', '.join(sorted(damaged)[:3])} ...)"
        )
        return
    root = files.root
    nodes = {name: read_whole(root, f"nodes/{name}") for name in NODE_ARRAYS}
    if not _check_nodes(nodes, report):
        return
    _check_partition(nodes, report)
    _check_slots(root, meta, nodes, report)
    if "cells" in members:
        _check_cells(root, meta, report)
    if terrain is None:
        return
    try:
        decoder = PatchDecoder(root, meta, nodes["strategies"], nodes["patch_slot"])
    except (UnsupportedTree, KeyError) as exc:
        report.not_checked.append(f"errors: {exc}")
        return
    _check_errors(nodes, meta, terrain, decoder, report)


# -- 1, 2: metadata and chunks -----------------------------------------------------------------


def _check_metadata(files: StoreFiles, members: dict[str, Any], report: VerifyReport) -> set[str]:
    check = report.check("metadata", "every zarr.json matches the root's metadata_crc32c")
    sums = files.attrs.get("metadata_crc32c")
    if not isinstance(sums, dict):
        check.items += 1
        check.fail("zarr.json", "metadata_crc32c", "missing")
        return {"zarr.json"}
    damaged = set()
    on_disk = {k[: -len("/zarr.json")] for k in files.keys if k.endswith("/zarr.json")}
    for path in sorted(set(sums) | on_disk):
        check.items += 1
        node = members.get(path)
        if node is None:
            check.fail(f"{path}/zarr.json", sums.get(path), "unreadable or missing")
            damaged.add(path)
        elif path not in sums:
            check.fail(f"{path}/zarr.json", "not listed", _metadata_crc(node))
        elif _metadata_crc(node) != int(sums[path]):
            check.fail(f"{path}/zarr.json", int(sums[path]), _metadata_crc(node))
            damaged.add(path)
    return damaged


def _check_chunks(files: StoreFiles, members: dict[str, Any], report: VerifyReport) -> set[str]:
    """Presence and decoding of every chunk; the paths of damaged arrays."""
    import zarr

    present = report.check("chunks", "every chunk of every array's grid is on disk")
    decode = report.check("decode", "every chunk decodes and passes its crc32c")
    damaged: set[str] = set()
    expected: set[str] = set()
    for path, arr in sorted(members.items()):
        if not isinstance(arr, zarr.Array):
            continue
        for key, coords in expected_chunk_keys(path, arr):
            expected.add(key)
            present.items += 1
            decode.items += 1
            if key not in files.keys:
                present.fail(key, "chunk", "missing")
                damaged.add(path)
                continue
            try:
                np.asarray(arr[chunk_selection(arr, coords)])
            except Exception as exc:  # blosc, crc32c and zarr errors alike
                decode.fail(key, "decodes", f"{type(exc).__name__}: {exc}"[:120])
                damaged.add(path)
    stray = sorted(k for k in files.keys if "/c/" in k and k not in expected)
    report.figures["chunks"] = len(expected)
    report.figures["stray_chunks"] = len(stray)
    return damaged


def _check_cells(root: Any, meta: dict[str, Any], report: VerifyReport) -> None:
    """``cells``: the per-cell figures (an update's) are whole, and reduce to the error and
    data count of the grid patch with their index, where one is stored."""
    check = report.check("cells", "per-cell figures are whole and reduce to their patches'")
    index = read_whole(root, "cells/index").astype(np.int64).reshape(-1, 6)
    start = read_whole(root, "cells/start").astype(np.int64)
    error = read_whole(root, "cells/error")
    count = read_whole(root, "cells/count")
    stats: dict[tuple[int, ...], np.ndarray] = {}
    if "grid" in (meta.get("strategy_names") or []):
        rows = read_whole(root, "patches/grid/index").reshape(-1, 6).tolist()
        values = read_whole(root, "patches/grid/stats").reshape(-1, 4)
        stats = {tuple(r): values[i] for i, r in enumerate(rows)}
    if len(start) != len(index) + 1 or start[-1] != len(error) or len(count) != len(error):
        check.items += 1
        check.fail("cells/start", len(index) + 1, len(start))
        return
    for i, (r0, r1, c0, c1, sr, sc) in enumerate(index.tolist()):
        check.items += 1
        cells = math.ceil((r1 - r0) / sr) * math.ceil((c1 - c0) / sc)
        a, b = int(start[i]), int(start[i + 1])
        if b - a != cells:
            check.fail(f"cells {i}", cells, b - a)
            continue
        found = stats.get((r0, r1, c0, c1, sr, sc))
        if found is not None and (
            error[a:b].max() != found[0] or int(count[a:b].sum()) != int(found[3])
        ):
            check.fail(f"cells {i}", float(found[0]), float(error[a:b].max()))


# -- 3: terrain --------------------------------------------------------------------------------


def _check_terrain(
    files: StoreFiles, members: dict[str, Any], terrain: Any, damaged: set[str], report
) -> None:
    from approxtree.geometry.grid import Grid

    check = report.check("terrain", "the stored terrain is the source's")
    kind = (files.attrs.get("meta") or {}).get("terrain_kind")
    check.items += 1
    if "terrain/heights" in members and kind == "grid":
        if not isinstance(terrain, Grid):
            check.fail("terrain", "a grid", type(terrain).__name__)
            return
        attrs = dict(members["terrain"].attrs).get("attrs", {})
        stored = np.array(attrs.get("transform", [np.nan] * 6), dtype=np.float64)[:6]
        given = np.array(list(terrain.transform)[:6], dtype=np.float64)
        heights = members["terrain/heights"]
        offset = tuple(attrs.get("index_offset", (0, 0)))
        if not np.allclose(stored, given, rtol=1e-12, atol=0) or offset != tuple(
            getattr(terrain, "index_offset", (0, 0))
        ):
            check.fail("terrain/transform", stored.tolist(), given.tolist())
            return
        if tuple(heights.shape) != tuple(terrain.shape):
            check.fail("terrain/heights shape", list(heights.shape), list(terrain.shape))
            return
        if "terrain/heights" in damaged:
            return
        for key, coords in expected_chunk_keys("terrain/heights", heights):
            sel = chunk_selection(heights, coords)
            check.items += 1
            mine = np.asarray(heights[sel], dtype=np.float64)
            theirs = np.asarray(terrain.heights[sel], dtype=np.float64)
            same = (mine == theirs) | (np.isnan(mine) & np.isnan(theirs))
            if not same.all():
                bad = int((~same).sum())
                check.fail(key, "the source's heights", f"{bad} heights differ", float(bad))
        return
    if "terrain/vertices" in members and kind in ("tin", "tinpointset"):
        if "terrain/vertices" in damaged:
            return
        mine = np.asarray(members["terrain/vertices"][...], dtype=np.float64)
        theirs = np.asarray(terrain.points(), dtype=np.float64)
        if mine.shape != theirs.shape or not np.array_equal(
            mine[np.lexsort(mine.T[::-1])], theirs[np.lexsort(theirs.T[::-1])]
        ):
            check.fail("terrain/vertices", f"{len(theirs)} source points", f"{len(mine)} stored")
        return
    report.not_checked.append(f"terrain: a stored {kind!r} terrain is not compared")


# -- 4: node table -----------------------------------------------------------------------------


def _check_nodes(nodes: dict[str, np.ndarray], report: VerifyReport) -> bool:
    """The table's shape and links; False when it is too broken to go on."""
    check = report.check("nodes", "the node table links parents, children and levels")
    n = len(nodes["errors"])
    report.figures["nodes"] = n
    check.items = n
    widths = {"rects": 4, "bboxes": 6}
    for name, a in nodes.items():
        if len(a) != n or (name in widths and a.shape[1:] != (widths[name],)):
            check.fail(f"nodes/{name}", f"{n} rows", list(a.shape))
    if not check.ok or n == 0:
        return False
    levels, parents = nodes["levels"].astype(np.int64), nodes["parents"].astype(np.int64)
    start, count = nodes["child_start"].astype(np.int64), nodes["child_count"].astype(np.int64)
    if levels[0] != 0 or parents[0] >= 0:
        check.fail("node 0", "the root (level 0, no parent)", f"level {levels[0]}")
    has = np.flatnonzero(count > 0)
    wild = has[(start[has] < 1) | (start[has] + count[has] > n)]
    for i in wild[:10].tolist():
        check.fail(f"node {i}", "children inside the table", f"{start[i]}+{count[i]}")
    if len(wild):
        return False
    # Each child names its parent, one level deeper; each node but the root is someone's child.
    owner = np.repeat(has, count[has])
    first = np.repeat(np.cumsum(count[has]) - count[has], count[has])
    child = start[owner] + np.arange(len(owner)) - first
    wrong = np.flatnonzero((parents[child] != owner) | (levels[child] != levels[owner] + 1))
    for j in wrong[:10].tolist():
        check.fail(f"node {child[j]}", f"child of node {owner[j]}", f"parent {parents[child[j]]}")
    orphans = np.setdiff1d(np.arange(1, n), child)
    for i in orphans[:10].tolist():
        check.fail(f"node {i}", "a parent's child", "no parent lists it")
    check.failures += max(0, len(wrong) - 10) + max(0, len(orphans) - 10)
    return check.ok


def _check_partition(nodes: dict[str, np.ndarray], report: VerifyReport) -> None:
    check = report.check("partition", "each node's children partition its rectangle")
    rects = nodes["rects"].astype(np.float64)
    start, count = nodes["child_start"].astype(np.int64), nodes["child_count"].astype(np.int64)
    has = np.flatnonzero(count > 0)
    check.items = len(has)
    if not len(has):
        return
    area = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
    scale = np.maximum(np.abs(rects[has]).max(axis=1), 1.0)
    slack = 1e-9 * scale
    total = np.zeros(len(has))
    outside = np.zeros(len(has), dtype=bool)
    overlap = np.zeros(len(has))
    for a in range(int(count.max())):
        ca = np.where(count[has] > a, start[has] + a, -1)
        ok = ca >= 0
        r = rects[np.maximum(ca, 0)]
        total += np.where(ok, area[np.maximum(ca, 0)], 0.0)
        p = rects[has]
        out = (r[:, 0] < p[:, 0] - slack) | (r[:, 1] < p[:, 1] - slack)
        out |= (r[:, 2] > p[:, 2] + slack) | (r[:, 3] > p[:, 3] + slack)
        outside |= ok & out
        for b in range(a + 1, int(count.max())):
            cb = np.where(count[has] > b, start[has] + b, -1)
            q = rects[np.maximum(cb, 0)]
            w = np.minimum(r[:, 2], q[:, 2]) - np.maximum(r[:, 0], q[:, 0])
            h = np.minimum(r[:, 3], q[:, 3]) - np.maximum(r[:, 1], q[:, 1])
            overlap += np.where(ok & (cb >= 0), np.maximum(w, 0) * np.maximum(h, 0), 0.0)
    parent_area = area[has]
    tol = 1e-9 * np.maximum(parent_area, 1e-300)
    bad = outside | (np.abs(total - parent_area) > tol) | (overlap > tol)
    for j in np.flatnonzero(bad).tolist():
        i = int(has[j])
        check.fail(f"node {i}", f"area {parent_area[j]:.6g}", f"children {total[j]:.6g}")


def _check_slots(root: Any, meta: dict[str, Any], nodes: dict[str, np.ndarray], report) -> None:
    check = report.check("patches", "every node has its patch, and its record decodes")
    names = list(meta.get("strategy_names", []))
    strategies, slots = nodes["strategies"].astype(np.int64), nodes["patch_slot"].astype(np.int64)
    n = len(strategies)
    check.items = n
    for i in np.flatnonzero((strategies < 0) | (strategies >= len(names)))[:10].tolist():
        check.fail(f"node {i}", f"a strategy of {names}", int(strategies[i]))
    for s, name in enumerate(names):
        mine = np.flatnonzero(strategies == s)
        try:
            back = np.asarray(root[f"patches/{name}/node"][...], dtype=np.int64)
        except Exception:
            check.fail(f"patches/{name}", "a patch group", "missing")
            continue
        slot = slots[mine]
        wrong = (slot < 0) | (slot >= len(back))
        wrong[~wrong] = back[slot[~wrong]] != mine[~wrong]
        for i in mine[wrong][:10].tolist():
            check.fail(f"node {i}", f"its {name} patch", f"slot {slots[i]}")
        if len(back) != len(mine):
            check.fail(f"patches/{name}", f"{len(mine)} patches", len(back))


# -- 5: errors ---------------------------------------------------------------------------------


def _check_errors(nodes, meta, terrain, decoder: PatchDecoder, report: VerifyReport) -> None:
    errors = report.check("errors", "each node's error is the true max |h_TN − h_T| or more")
    rects = nodes["rects"].astype(np.float64)
    claimed = nodes["errors"].astype(np.float64)
    measure = measure_for(terrain, snap=True)
    found = measure.errors(rects, decoder.triangles, _TOL)
    measured = np.where(found.measured > 0, found.err, 0.0)
    measured = np.where((found.uncovered > 0) | (found.holes > 0), np.inf, measured)
    zmax = max(abs(v) for v in terrain.z_range) if terrain.point_count else 0.0
    slack = 1e-9 * (1.0 + zmax)
    n = len(claimed)
    errors.items = n
    for i in np.flatnonzero(~claims_hold(measured, claimed, slack)).tolist():
        errors.fail(_address(nodes, i, found), claimed[i], measured[i], measured[i] - claimed[i])
    for i in np.flatnonzero(decoder.bad).tolist():
        report.checks["patches"].fail(f"node {i}", "a record that decodes", "malformed")
    report.figures["data_points"] = int(found.measured[0] + found.uncovered[0])
    report.figures["worst_node_error"] = float(measured.max(initial=0.0))
    finite = np.isfinite(claimed) & (claimed > 0)
    ratio = measured[finite] / claimed[finite]
    report.figures["worst_measured_over_claimed"] = float(ratio.max(initial=0.0))
    _check_epsilon(nodes, meta, measured, slack, report)
    _check_bboxes(nodes, decoder, found, report)


def _address(nodes, i: int, found) -> str:
    where = found.worst[i]
    at = f" at ({where[0]:.6g}, {where[1]:.6g})" if np.isfinite(where).all() else ""
    return f"node {i} (level {int(nodes['levels'][i])}){at}"


def _check_epsilon(nodes, meta, measured: np.ndarray, slack: float, report) -> None:
    epsilon = (meta.get("params") or {}).get("epsilon")
    if not isinstance(epsilon, (int, float)) or not math.isfinite(epsilon):
        report.not_checked.append("epsilon: the store records no ε")
        return
    check = report.check("epsilon", f"every leaf is within the tree's ε = {epsilon:g}")
    leaves = np.flatnonzero(nodes["child_count"] == 0)
    check.items = len(leaves)
    over = leaves[~claims_hold(measured[leaves], np.full(len(leaves), float(epsilon)), slack)]
    for i in over.tolist():
        check.fail(f"node {i} (leaf)", float(epsilon), measured[i], measured[i] - epsilon)


def _check_bboxes(nodes, decoder: PatchDecoder, found, report) -> None:
    check = report.check("bboxes", "each B_N holds its patch's vertices and data points")
    boxes = nodes["bboxes"].astype(np.float64)
    lo, hi = decoder.vmin.copy(), decoder.vmax.copy()
    lo[:, 2] = np.minimum(lo[:, 2], found.zmin)
    hi[:, 2] = np.maximum(hi[:, 2], found.zmax)
    scale = 1e-9 * np.maximum(np.abs(boxes).max(axis=1, initial=0.0), 1.0)[:, None]
    with np.errstate(invalid="ignore"):
        below = np.isfinite(lo) & ~(lo >= boxes[:, :3] - scale)
        above = np.isfinite(hi) & ~(hi <= boxes[:, 3:] + scale)
    bad = np.flatnonzero(below.any(axis=1) | above.any(axis=1))
    check.items = len(boxes)
    for i in bad.tolist():
        check.fail(
            f"node {i}",
            [round(float(v), 6) for v in boxes[i]],
            [round(float(v), 6) for v in (*lo[i], *hi[i])],
        )
