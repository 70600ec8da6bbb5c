"""A point quadtree's arrays in a saved tree: what ``PointQuadtree.to_sections`` writes and
``PointQuadtree.from_sections`` reads back (the terrain is stored apart, as for every tree).

The "quadtree" section holds the header (δ, the lattice square's size and origin), the points
in Z-order with their Morton codes, the nodes (level, i, j) and whether each is internal, the
measured node errors, the lattice heights, and per leaf its insertion order with the error
after each insertion. ``SECTION_VERSION`` numbers this layout.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from approxtree._version import __version__
from approxtree.errors import StoreError

if TYPE_CHECKING:
    from approxtree.tree.point_quadtree import PointQuadtree

#: ``meta["tree_kind"]`` of a point quadtree in a saved tree.
TREE_KIND = "point_quadtree"
#: Version of the "quadtree" section's layout.
SECTION_VERSION = 1


def to_sections(q: PointQuadtree) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(meta, arrays) of the quadtree ``q`` for a tree store (terrain apart)."""
    leaves = [q.node_keys[r] for r in np.flatnonzero(~q.internal)]
    lattice = sorted(q.lattice.items())
    arrays = {
        "header": np.array([q.max_points, q.size, q.x0, q.y0], dtype="<f8"),
        "points": q.points,
        "codes": q.codes,
        "nodes": np.array(q.node_keys, dtype="<i8").reshape(-1, 3),
        "internal": q.internal,
        "node_errors": q.node_errors,
        "lattice_keys": np.array([k for k, _ in lattice], dtype="<i8").reshape(-1, 2),
        "lattice_xyz": np.array([v for _, v in lattice], dtype="<f8").reshape(-1, 3),
        "order_counts": np.array([len(q.orders[n][0]) for n in leaves], dtype="<i8"),
        "orders": np.concatenate([q.orders[n][0] for n in leaves]).astype("<i8"),
        "order_errors": np.concatenate([q.orders[n][1] for n in leaves]),
    }
    meta = {
        "library": f"approxtree {__version__}",
        "tree_kind": TREE_KIND,
        "section_version": SECTION_VERSION,
        "terrain_kind": q.terrain.kind,
    }
    return meta, arrays


def checked_arrays(
    meta: dict[str, Any], raw: dict[str, np.ndarray], path: str
) -> dict[str, np.ndarray]:
    """The section's arrays (copies) once its layout version is one this approxtree reads;
    StoreError naming ``path`` otherwise."""
    if meta.get("section_version") != SECTION_VERSION:
        raise StoreError(
            f"{path} has point quadtree layout {meta.get('section_version')!r}; this "
            f"approxtree reads {SECTION_VERSION}. Rebuild it with this version."
        )
    arrays = {k: np.array(v) for k, v in raw.items()}
    if "header" not in arrays or len(arrays["header"]) < 4:
        raise StoreError(f"{path} holds a malformed point quadtree (no header); rebuild it.")
    return arrays


def max_points(arrays: dict[str, np.ndarray]) -> int:
    """δ, the most points a leaf holds, from the header."""
    return int(arrays["header"][0])


def fill(q: PointQuadtree, a: dict[str, np.ndarray], path: str) -> None:
    """Set the built figures of ``q`` (made with ``_build=False``) from the section's arrays;
    StoreError naming ``path`` for arrays that do not fit together."""
    try:
        _fill(q, a)
    except (KeyError, ValueError, IndexError) as exc:
        raise StoreError(f"{path} holds a malformed point quadtree ({exc}); rebuild it.") from exc


def _fill(q: PointQuadtree, a: dict[str, np.ndarray]) -> None:
    header = a["header"]
    q.size, q.x0, q.y0 = float(header[1]), float(header[2]), float(header[3])
    q.points, q.codes = a["points"].astype(np.float64), a["codes"].astype(np.int64)
    nodes = [(int(n[0]), int(n[1]), int(n[2])) for n in a["nodes"]]
    q.children = dict(zip(nodes, a["internal"].astype(bool).tolist(), strict=True))
    q.lattice = {
        (int(k[0]), int(k[1])): (float(v[0]), float(v[1]), float(v[2]))
        for k, v in zip(a["lattice_keys"], a["lattice_xyz"], strict=True)
    }
    # The lookup tables the build makes, then the figures the store keeps.
    q._index()
    q.node_errors = a["node_errors"].astype(np.float64)
    if len(q.node_errors) != len(q):
        raise ValueError("one error per node expected")
    q.errors = dict(zip(q.node_keys, q.node_errors.tolist(), strict=True))
    q.orders = {}
    o = e = 0
    leaves = [q.node_keys[r] for r in np.flatnonzero(~q.internal)]
    for leaf, n in zip(leaves, a["order_counts"].tolist(), strict=True):
        q.orders[leaf] = (
            a["orders"][o : o + n].astype(np.int64),
            a["order_errors"][e : e + n + 1],
        )
        o, e = o + n, e + n + 1
    q._order_error_table()
