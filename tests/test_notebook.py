"""Jupyter: PNG previews of frames, trees and terrains, the orbiting widget, the example
notebook run by nbclient."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from PIL import Image

from approxtree.errors import ContextUnavailableError
from approxtree.geometry import Grid
from approxtree.tree import ApproximationTree

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gl():
    """Skip without an EGL OpenGL context (the previews then return None, tested below)."""
    from approxtree.render.context import create_context

    try:
        ctx = create_context()
    except ContextUnavailableError as exc:
        pytest.skip(f"no OpenGL context: {exc}")
    ctx.release()


def hills(n: int = 160) -> Grid:
    y, x = np.mgrid[0:n, 0:n] / n
    z = 300 + 80 * np.sin(6 * x) * np.cos(5 * y) + 30 * np.sin(23 * x * y)
    return Grid(z.astype(np.float32), Affine(30.0, 0, 600000.0, 0, -30.0, 4000000.0))


@pytest.fixture(scope="module")
def tree():
    return ApproximationTree.build(hills(), epsilon=1.0, progress=False)


def decode(png: bytes) -> np.ndarray:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(Image.open(io.BytesIO(png)))


def test_tree_and_terrain_previews_are_fitted_pngs(gl, tree):
    from approxtree.notebook import PREVIEW_SIZE, preview, preview_tree, repr_png

    w, h = PREVIEW_SIZE
    for obj, drawn in ((tree, tree), (tree.terrain, None)):
        image = decode(repr_png(obj))
        assert image.shape == (h, w, 4)
        drawn = drawn or preview_tree(obj)
        # The preview is the fitted overview on a sky: the same frame, drawn transparent,
        # shows how much of the picture the terrain covers.
        assert np.array_equal(image, preview(drawn).image)
        coverage = (preview(drawn, background="transparent").image[..., 3] > 0).mean()
        assert coverage >= 0.5, coverage
        assert (image[..., 3] == 255).all()  # opaque sky around it


def test_frame_shows_its_image(gl, tree):
    from approxtree.notebook import preview

    frame = preview(tree, size=(320, 200), background="transparent")
    assert np.array_equal(decode(frame._repr_png_()), frame.image)
    frame.image = None
    assert frame._repr_png_() is None


def test_no_gl_context_gives_none_never_an_error(monkeypatch, tree):
    import approxtree.render.engine as engine_module
    from approxtree.notebook import repr_png

    def refuse():
        raise ContextUnavailableError("no EGL here (test)")

    monkeypatch.setattr(engine_module, "create_context", refuse)
    assert repr_png(tree) is None
    assert repr_png(tree.terrain) is None


def test_widget_orbits_on_a_drag_and_zooms_on_the_wheel(gl, tree):
    from approxtree.notebook import TerrainWidget

    widget = TerrainWidget(tree, size=(320, 180))
    try:
        first = widget.get_frame()
        assert first.shape == (180, 320, 4) and first.dtype == np.uint8
        assert np.array_equal(widget.get_frame(), first)  # nothing moved, same picture
        yaw = widget.view.orbit.yaw
        widget.handle_event(
            {
                "event_type": "pointer_down",
                "x": 100,
                "y": 90,
                "button": 1,
                "buttons": (1,),
                "modifiers": (),
            }
        )
        widget.handle_event(
            {"event_type": "pointer_move", "x": 160, "y": 100, "buttons": (1,), "modifiers": ()}
        )
        widget.handle_event(
            {
                "event_type": "pointer_up",
                "x": 160,
                "y": 100,
                "button": 1,
                "buttons": (),
                "modifiers": (),
            }
        )
        assert widget.view.orbit.yaw != yaw
        dragged = widget.get_frame()
        assert np.abs(dragged.astype(int) - first).mean() > 2.0
        distance = widget.view.orbit.distance
        widget.handle_event(
            {"event_type": "wheel", "x": 160, "y": 90, "dx": 0, "dy": -300, "modifiers": ()}
        )
        assert widget.view.orbit.distance < distance
        assert not np.array_equal(widget.get_frame(), dragged)
        widget.handle_event({"event_type": "resize", "width": 200, "height": 100, "pixel_ratio": 1})
        assert widget.get_frame().shape == (100, 200, 4)
    finally:
        widget.close()


def test_example_notebook_runs_and_shows_pictures(gl, tmp_path):
    import nbclient
    import nbformat

    nb = nbformat.read(ROOT / "examples" / "notebook.ipynb", as_version=4)
    # Run from the repository root, like the tests (../shared/data when present).
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(ROOT)}}
    )
    client.execute()
    code = [c for c in nb.cells if c.cell_type == "code"]
    outputs = [o for c in code for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    # The cells ending with the terrain, the tree and the frame display 640 × 360 pictures.
    for name in ("terrain", "tree", "frame"):
        (cell,) = [c for c in code if c.source.strip().splitlines()[-1] == name]
        pngs = [o.data["image/png"] for o in cell.outputs if "image/png" in o.get("data", {})]
        assert len(pngs) == 1, f"the {name} cell shows no picture"
        assert decode(base64.b64decode(pngs[0])).shape == (360, 640, 4)
    view = "application/vnd.jupyter.widget-view+json"
    widgets = [o for o in outputs if view in o.get("data", {})]
    assert widgets, "the widget cell shows no widget"


def test_widget_redraws_a_tree_updated_in_a_later_cell(gl):
    """After ``tree.update`` the widget's refresh (run after every cell) asks for a frame,
    which shows the change: its Engine followed the update (``Engine.follow_tree``, whose
    cache keeping tests/test_update_render.py checks) without being recreated."""
    from approxtree.geometry.rect import Rect
    from approxtree.notebook import TerrainWidget

    grid = hills()
    tree = ApproximationTree.build(grid, epsilon=1.0, progress=False)
    widget = TerrainWidget(tree, size=(320, 180))
    draws = []
    widget.request_draw = lambda: draws.append(1)
    try:
        first = widget.get_frame()
        assert not widget.refresh() and not draws
        t = grid.transform
        # 30 × 30 cells east of the centre raised 20 m within the terrain's z range.
        r0, c0, n = 60, 90, 30
        lo, hi = grid.z_range
        old = np.array(grid.heights[r0 : r0 + n, c0 : c0 + n], dtype=np.float64)
        heights = np.where(old > lo, np.minimum(old + 20.0, hi), old)
        x0, y0 = t @ (c0, r0 + n)
        x1, y1 = t @ (c0 + n, r0)
        tree.update(Rect(x0, y0, x1, y1), heights)
        assert widget.refresh() and draws == [1]
        second = widget.get_frame()
        assert not np.array_equal(first, second)
        assert "gpu_dropped" in widget.view.engine.update_figures
        assert not widget.refresh() and draws == [1]
    finally:
        widget.close()
