"""Meshes as the objects users already work with: ``trimesh.Trimesh`` and ``pyvista.PolyData``.

``MeshConversions`` gives ``to_trimesh()`` and ``to_pyvista()`` to anything with ``vertices``
(n, 3) float64 world coordinates and ``triangles`` (m, 3) indices, counter-clockwise seen from
above: geometry patches (``node.patch``), the mesh of a whole cut (``tree.cut_mesh``) and a
point quadtree's view-dependent mesh (``LODMesh``). Both conversions keep every vertex and
every triangle as they are (no merging, no reordering, float64), with the height z as point
data and the owner's per-face arrays (``_face_data``: the node of each face of a cut) as face
data.

trimesh is a dependency; pyvista is optional and imported only when ``to_pyvista`` is called
(an ApproxTreeError naming ``pip install pyvista`` when it is missing).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from approxtree.errors import ApproxTreeError


def as_trimesh(
    vertices: np.ndarray, triangles: np.ndarray, face_data: dict[str, np.ndarray] | None = None
) -> Any:
    """A ``trimesh.Trimesh`` of (n, 3) float64 vertices and (m, 3) triangles, unprocessed
    (same vertices and faces, in order), with vertex attribute "z" and the face attributes
    of ``face_data`` ((m,) arrays by name)."""
    import trimesh

    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    return trimesh.Trimesh(
        v,
        t,
        process=False,
        vertex_attributes={"z": v[:, 2].copy()},
        face_attributes=dict(face_data or {}),
    )


def as_pyvista(
    vertices: np.ndarray, triangles: np.ndarray, face_data: dict[str, np.ndarray] | None = None
) -> Any:
    """A ``pyvista.PolyData`` of (n, 3) float64 vertices and (m, 3) triangles, with point data
    "z" and the cell data of ``face_data`` ((m,) arrays by name)."""
    try:
        import pyvista
    except ImportError:
        raise ApproxTreeError(
            "to_pyvista needs pyvista, which is not installed: pip install pyvista "
            "(or use to_trimesh, which needs nothing more)."
        ) from None
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    # Typed as a plain array: pyvista annotates faces as an array of Python ints (dtype[int]),
    # which no int64 array matches, though int64 is what it stores.
    t: np.ndarray = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
    mesh = pyvista.PolyData.from_regular_faces(v, t)
    mesh.point_data["z"] = v[:, 2].copy()
    for name, values in (face_data or {}).items():
        mesh.cell_data[name] = np.asarray(values)
    return mesh


class _Mesh(Protocol):
    """What the conversions read: attributes or properties alike."""

    @property
    def vertices(self) -> np.ndarray: ...

    @property
    def triangles(self) -> np.ndarray: ...

    def _face_data(self) -> dict[str, np.ndarray]: ...


class MeshConversions:
    """``to_trimesh()`` and ``to_pyvista()`` for a class with ``vertices`` (n, 3) float64 world
    coordinates and ``triangles`` (m, 3) counter-clockwise seen from above (attributes or
    properties: ``_Mesh``); a class with face data overrides ``_face_data``."""

    def _face_data(self) -> dict[str, np.ndarray]:
        """(m,) arrays kept as face data by name (none by default)."""
        return {}

    def to_trimesh(self: _Mesh) -> Any:
        """The mesh as a ``trimesh.Trimesh``: the same vertices (float64 world) and triangles,
        vertex attribute "z" (and face attributes, e.g. "node" for a cut)."""
        return as_trimesh(self.vertices, self.triangles, self._face_data())

    def to_pyvista(self: _Mesh) -> Any:
        """The mesh as a ``pyvista.PolyData``: the same vertices (float64 world) and
        triangles, point data "z" (and cell data, e.g. "node" for a cut). Needs pyvista
        (``pip install pyvista``)."""
        return as_pyvista(self.vertices, self.triangles, self._face_data())
