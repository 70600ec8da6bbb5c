"""Python data in, Python data out.

In: an xarray / rioxarray DataArray is a terrain (``Grid(da)``, ``open_terrain(da)``,
``ApproximationTree.build(da)``) placed by its own georeference, as the file it came from
reads; what cannot be placed is refused saying why; a dask-backed one is read by windows.
Out: a geometry patch, a cut (``tree.cut_mesh``: a frame's nodes or the leaves) and a point
quadtree's view mesh as ``trimesh.Trimesh`` and ``pyvista.PolyData``, with every vertex and
triangle as the engine has them.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from affine import Affine
from conftest import data_file

import approxtree as at
from approxtree import ApproximationTree, ApproxTreeError, Grid, InvalidParameterError

xr = pytest.importorskip("xarray")

NODE_ARRAYS = ("rects", "errors", "bboxes", "levels", "parents", "child_start", "child_count")


def same_tree(a: ApproximationTree, b: ApproximationTree) -> None:
    """Assert that two trees are equal node for node, patches included."""
    assert len(a) == len(b)
    for name in (*NODE_ARRAYS, "strategies"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for i in a.leaves[:: max(1, len(a.leaves) // 16)]:
        np.testing.assert_array_equal(a.patch(i).vertices, b.patch(i).vertices)
        np.testing.assert_array_equal(a.patch(i).triangles, b.patch(i).triangles)


# -- DataArrays in --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nc_path(data_dir):
    return data_file(data_dir, "nc/elev_ned_30m.tif")


@pytest.mark.parametrize("chunks", [None, {"x": 128, "y": 128}], ids=["numpy", "dask"])
def test_rioxarray_dataarray_reads_as_its_file(nc_path, chunks):
    """rioxarray.open_rasterio(DEM) gives the domain, cell size, CRS, heights and tree of
    open_terrain(DEM), numpy- or dask-backed (the latter read by windows)."""
    rioxarray = pytest.importorskip("rioxarray")
    da = rioxarray.open_rasterio(nc_path, chunks=chunks)
    ref = at.open_terrain(nc_path)
    for grid in (Grid(da), at.open_terrain(da)):
        assert grid.domain == ref.domain
        assert grid.cell_size == ref.cell_size == (30.0, 30.0)
        assert grid.crs == ref.crs == "EPSG:32119"
        assert grid.is_windowed == (chunks is not None)
        np.testing.assert_array_equal(np.asarray(grid.heights[:, :]), ref.heights)
    same_tree(ApproximationTree.build(da, epsilon=2.0), ApproximationTree.build(ref, epsilon=2.0))


def test_rioxarray_nodata_is_nodata(data_dir):
    """The USGS DEM's nodata (−32767) is nodata whether rioxarray masked it or not."""
    rioxarray = pytest.importorskip("rioxarray")
    path = data_file(data_dir, "edge/SainteHelens.dem")
    ref = at.open_terrain(path)
    for masked in (False, True):
        grid = at.open_terrain(rioxarray.open_rasterio(path, masked=masked))
        assert grid.nodata == ref.nodata == -32767.0
        assert grid.point_count == ref.point_count == 148885
        np.testing.assert_array_equal(grid.heights, ref.heights)


def hand_built(ys: np.ndarray, xs: np.ndarray, heights: np.ndarray, **kw) -> object:
    """A DataArray (y, x) with 1-D coordinates, as a user makes one."""
    return xr.DataArray(heights, dims=("y", "x"), coords={"y": ys, "x": xs}, **kw)


def test_hand_built_dataarray_is_placed_by_its_coordinates():
    """1-D x/y coordinates are cell centres; y increasing (south first) or x decreasing is
    turned so that row 0 is north; _FillValue and NaN are nodata; the crs attribute is kept."""
    rows, cols = 6, 8
    north_up = np.arange(rows * cols, dtype=np.float64).reshape(rows, cols) + 100.0
    north_up[1, 2], north_up[4, 5] = -9999.0, np.nan
    ys = 5000.0 - 25.0 * (np.arange(rows) + 0.5)  # north first
    xs = 300.0 + 10.0 * (np.arange(cols) + 0.5)
    expected = Affine(10.0, 0.0, 300.0, 0.0, -25.0, 5000.0)
    variants = [
        hand_built(ys, xs, north_up),
        hand_built(ys[::-1], xs, north_up[::-1]),  # south first
        hand_built(ys, xs[::-1], north_up[:, ::-1]),  # east first
    ]
    for da in variants:
        da.attrs.update(_FillValue=-9999.0, crs="EPSG:32119")
        grid = Grid(da)
        assert grid.transform.almost_equals(expected, precision=1e-9)
        assert grid.crs == "EPSG:32119" and grid.nodata == -9999.0
        assert grid.point_count == rows * cols - 2
        want = np.where(north_up == -9999.0, np.nan, north_up)
        np.testing.assert_array_equal(grid.heights, want)
        # h_T at the data point of row 0, column 0 (north-west) is that cell's height.
        assert grid.height_at(np.array([305.0]), np.array([4987.5]))[0] == pytest.approx(100.0)
    # A band of size 1 is dropped.
    banded = variants[0].expand_dims(band=[1])
    assert Grid(banded).domain == Grid(variants[0]).domain


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda h: hand_built([0.0, 1.0, 2.0, 4.0], [0.0, 1.0, 2.0], h), "irregular"),
        (
            lambda h: xr.DataArray(h, dims=("y", "x"), coords={"lat": (("y", "x"), h)}),
            "2-D coordinates",
        ),
        (
            lambda h: xr.DataArray(h, dims=("a", "b"), coords={"lon": (("a", "b"), h)}),
            "2-D coordinates",
        ),
        (
            lambda h: xr.DataArray(np.stack([h, h]), dims=("band", "y", "x")),
            "band: 2",
        ),
        (lambda h: hand_built([0.0, 1, 2, 3], [0.0, 1, 2], h.astype(str)), "not heights"),
        (lambda h: xr.DataArray(h, dims=("a", "b"), coords={"a": np.arange(4)}), "x .east."),
        (lambda h: hand_built([0.0, 0, 0, 0], [0.0, 1, 2], h), "do not advance"),
    ],
    ids=["irregular", "2-D coords", "curvilinear", "3 dims", "strings", "unnamed", "flat"],
)
def test_dataarray_that_cannot_be_placed_is_refused(make, match):
    """Irregular or 2-D coordinates, extra dims, non-numbers, unknown dims: an
    InvalidParameterError saying why, from Grid, open_terrain and ApproximationTree.build."""
    da = make(np.arange(12.0).reshape(4, 3))
    for call in (Grid, at.open_terrain, ApproximationTree.build):
        with pytest.raises(InvalidParameterError, match=match):
            call(da)


def test_open_terrain_takes_the_reader_options_of_a_dataarray():
    """open_terrain(da) takes nodata, crs and windowed, and refuses file options."""
    h = np.add.outer(np.arange(5.0), np.arange(6.0))
    h[2, 3] = np.nan
    da = hand_built(np.arange(5.0)[::-1], np.arange(6.0), h)
    assert at.open_terrain(da).point_count == 29
    assert at.open_terrain(da, nodata="fill").point_count == 30
    windowed = at.open_terrain(da, nodata="fill", windowed=True)
    assert windowed.is_windowed and np.isfinite(windowed.heights[2, 3])
    assert at.open_terrain(da, crs="EPSG:4326").crs == "EPSG:4326"
    with pytest.raises(InvalidParameterError, match=r"cell_size.*does not apply to a DataArray"):
        at.open_terrain(da, cell_size=2.0)


class CountingArray:
    """A numpy array seen by dask through __getitem__, counting the cells handed out."""

    def __init__(self, a: np.ndarray) -> None:
        self.a, self.shape, self.dtype, self.ndim = a, a.shape, a.dtype, a.ndim
        self.cells = 0

    def __getitem__(self, key):
        out = self.a[key]
        self.cells += out.size
        return out


def test_dask_dataarray_is_not_computed_whole():
    """A dask-backed DataArray is read by windows: h_T at one point computes one block, a
    quarter of the array here, never the whole."""
    dask_array = pytest.importorskip("dask.array")
    n = 1024
    source = CountingArray(np.add.outer(np.arange(n, dtype=np.float32), np.arange(n)))
    da = hand_built(
        np.arange(n)[::-1] + 0.5, np.arange(n) + 0.5, dask_array.from_array(source, chunks=128)
    )
    grid = Grid(da)
    assert grid.is_windowed and source.cells == 0
    assert grid.height_at(np.array([10.5]), np.array([n - 20.5]))[0] == pytest.approx(30.0)
    assert 0 < source.cells <= n * n // 4


# -- meshes out -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nc_tree(nc_path) -> ApproximationTree:
    return ApproximationTree.build(at.open_terrain(nc_path), epsilon=2.0, progress=False)


def check_mesh(mesh_vertices, mesh_faces, vertices, triangles) -> None:
    """Assert that a converted mesh has the very vertices (float64) and triangles."""
    assert mesh_vertices.dtype == np.float64
    np.testing.assert_array_equal(mesh_vertices, vertices)
    np.testing.assert_array_equal(mesh_faces, triangles)


def test_patch_to_trimesh_and_pyvista(nc_tree):
    """A node's patch converts to trimesh and pyvista with its vertices and triangles, z as
    point data, counter-clockwise faces seen from above, and pyvista's bounds its box."""
    pv = pytest.importorskip("pyvista")
    for node in (nc_tree.root, *nc_tree.root.children, nc_tree.node(int(nc_tree.leaves[-1]))):
        patch = node.patch
        tm = patch.to_trimesh()
        check_mesh(tm.vertices, tm.faces, patch.vertices, patch.triangles)
        np.testing.assert_array_equal(tm.vertex_attributes["z"], patch.vertices[:, 2])
        # Counter-clockwise from above: every face normal points up.
        assert (tm.face_normals[:, 2] > 0).all()
        mesh = patch.to_pyvista()
        assert isinstance(mesh, pv.PolyData)
        assert (mesh.n_points, mesh.n_cells) == (len(patch.vertices), len(patch.triangles))
        check_mesh(mesh.points, mesh.regular_faces, patch.vertices, patch.triangles)
        np.testing.assert_array_equal(mesh.point_data["z"], patch.vertices[:, 2])
        r, z = node.rect, patch.vertices[:, 2]
        assert tuple(mesh.bounds) == (r.xmin, r.xmax, r.ymin, r.ymax, z.min(), z.max())
        assert node.bbox[2] <= z.min() and z.max() <= node.bbox[5]


def test_cut_mesh_of_the_leaves_partitions_the_domain(nc_tree):
    """tree.cut_mesh() (the leaves) is every leaf patch in world coordinates, one face per
    patch triangle tagged by its node, covering the domain once (signed areas sum to it)."""
    cut = nc_tree.cut_mesh()
    leaves = nc_tree.leaves
    assert len(cut.triangles) == sum(len(nc_tree.patch(i).triangles) for i in leaves)
    assert np.array_equal(np.unique(cut.nodes), leaves) and not cut.skirt.any()
    v = cut.vertices[cut.triangles]
    area = 0.5 * np.cross(v[:, 1, :2] - v[:, 0, :2], v[:, 2, :2] - v[:, 0, :2])
    d = nc_tree.terrain.domain
    assert (area > 0).all()
    assert area.sum() == pytest.approx((d.xmax - d.xmin) * (d.ymax - d.ymin), rel=1e-12)
    tm = cut.to_trimesh()
    np.testing.assert_array_equal(tm.face_attributes["node"], cut.nodes)
    check_mesh(tm.vertices, tm.faces, cut.vertices, cut.triangles)


def test_cut_mesh_of_a_frame_is_what_it_drew(nc_tree):
    """tree.cut_mesh(frame.selection.nodes, skirts=True) has the triangles the frame drew,
    skirts included; without skirts, its nodes' patch triangles."""
    from approxtree.render import Cut, Engine, framing_camera

    with Engine(nc_tree) as engine:
        camera = framing_camera(nc_tree.bboxes[0], engine.scale, (320, 240))
        frame = engine.render(camera, (320, 240), Cut(alpha=1.0))
    nodes = frame.selection.nodes
    with_skirts = nc_tree.cut_mesh(nodes, skirts=True)
    assert len(with_skirts.triangles) == frame.stats["triangles"]
    assert with_skirts.skirt.any()
    plain = nc_tree.cut_mesh(nodes)
    assert len(plain.triangles) == sum(len(nc_tree.patch(i).triangles) for i in nodes)
    assert len(plain.triangles) == np.count_nonzero(~with_skirts.skirt)
    pv = pytest.importorskip("pyvista")
    mesh = with_skirts.to_pyvista()
    assert isinstance(mesh, pv.PolyData) and mesh.n_cells == frame.stats["triangles"]
    np.testing.assert_array_equal(mesh.cell_data["node"], with_skirts.nodes)


def test_cut_mesh_refuses_bad_node_ids(nc_tree):
    """Node ids outside the tree or not integers are an InvalidParameterError."""
    with pytest.raises(InvalidParameterError, match="node ids must lie"):
        nc_tree.cut_mesh(np.array([0, len(nc_tree)]))
    with pytest.raises(InvalidParameterError, match="1-D array of node ids"):
        nc_tree.cut_mesh(np.array([0.5]))


def test_point_quadtree_lod_mesh_to_trimesh():
    """A point quadtree's view mesh converts with its vertices, triangles and face nodes."""
    from approxtree.render.lod_cut import lod_mesh

    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (400, 2))
    z = 10 + 0.2 * xy[:, 0] + 3 * np.sin(xy[:, 1] / 7)
    quadtree = at.PointQuadtree(at.TINPointSet(np.column_stack([xy, z])), max_points=20)
    lod = lod_mesh(quadtree, (50.0, -150.0, 120.0), 60.0, 640)
    tm = lod.to_trimesh()
    check_mesh(tm.vertices, tm.faces, lod.vertices, lod.triangles)
    assert len(tm.face_attributes["node"]) == len(lod.triangles) > 0
    assert len(np.unique(lod.face_nodes)) == lod.nodes


def test_to_pyvista_without_pyvista_says_how_to_install_it(nc_tree, monkeypatch):
    """Without pyvista, to_pyvista fails when called with an ApproxTreeError naming
    `pip install pyvista` (approxtree imports and to_trimesh still work)."""
    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(ApproxTreeError, match="pip install pyvista"):
        nc_tree.root.patch.to_pyvista()
    assert len(nc_tree.root.patch.to_trimesh().faces) == len(nc_tree.root.patch.triangles)
