"""Clear errors instead of tracebacks or silent blanks (issue 13, item 5).

Each case ends in one ``Error:`` line and exit code 2 from the CLI, or an ApproxTreeError from
the API: a tree with nothing to draw, a field of view of 0, an output that cannot be written
(checked before the work), a bake into a folder whose parents do not exist. A frame that shows
no terrain says so in its stats and with a warning.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from approxtree import ApproximationTree
from approxtree.cli import main
from approxtree.errors import (
    ApproxTreeWarning,
    EmptyTerrainError,
    InvalidParameterError,
    StoreError,
)
from approxtree.geometry import Grid
from approxtree.render import Camera, Engine, overview_camera
from approxtree.render.frame import EmptyFrameWarning


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def assert_one_error_line(code: int, stderr: str, words: str) -> None:
    assert code == 2, stderr
    assert stderr.startswith("Error: ") and words in stderr, stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


def hills(rows: int = 24, cols: int = 32) -> np.ndarray:
    """(rows, cols) float64 smooth heights 60..140."""
    y, x = np.mgrid[0:rows, 0:cols]
    return 100 + 30 * np.sin(x / 4) + 10 * np.cos(y / 3)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with a small DEM (dem.npy) and its tree (hills.zarr)."""
    path = tmp_path_factory.mktemp("errors")
    np.save(path / "dem.npy", hills())
    ApproximationTree.build(Grid(hills()), epsilon=0.5, progress=False).save(path / "hills.zarr")
    return path


# -- a tree with nothing to draw ---------------------------------------------------------------


def one_point_tree() -> ApproximationTree:
    """The tree of a 5 × 5 grid with one valid cell centre: one point, no triangle."""
    heights = np.full((5, 5), np.nan)
    heights[2, 2] = 5.0
    return ApproximationTree.build(Grid(heights), epsilon=1.0, progress=False)


def test_rendering_a_tree_of_one_valid_point_is_a_clear_error(tmp_path):
    """Was moderngl's 'the buffer cannot be empty' traceback."""
    tree = one_point_tree()
    with pytest.raises(EmptyTerrainError, match="nothing to draw"):
        Engine(tree)
    tree.save(tmp_path / "one.zarr")
    code, _, err = run("render", tmp_path / "one.zarr", "--out", tmp_path / "one.png")
    assert_one_error_line(code, err, "nothing to draw")
    assert not (tmp_path / "one.png").exists()


def checkerboard_tree(columns: slice) -> ApproximationTree:
    """The tree of a 40 × 40 grid with nodata on every other cell centre of ``columns``
    (there no two valid points are neighbours: the patches hold no triangle)."""
    heights = hills(40, 40)
    checker = np.zeros((40, 40), dtype=bool)
    checker[:, columns] = (np.add.outer(np.arange(40), np.arange(40)) % 2 == 1)[:, columns]
    heights[checker] = np.nan
    return ApproximationTree.build(Grid(heights), epsilon=0.5, max_points=64, progress=False)


def test_patches_without_triangles_are_skipped_not_fatal():
    """Nodes whose patches hold no triangle (a checkerboard of nodata on the east half) are
    drawn beside nodes that do (was a GL error); a tree of such nodes only draws an empty
    frame that says why."""
    tree = checkerboard_tree(slice(20, None))
    with Engine(tree) as engine:
        frame = engine.render(overview_camera(tree.bboxes[0], engine.scale), (64, 48))
    counts = [len(tree.patch(int(i)).triangles) for i in frame.selection.nodes]
    assert 0 in counts and max(counts) > 0
    assert frame.stats["triangles"] > 0 and frame.stats["empty"] is False
    assert frame.image[..., 3].any()
    tree = checkerboard_tree(slice(None))
    with Engine(tree) as engine:
        with pytest.warns(EmptyFrameWarning, match="no triangle"):
            frame = engine.render(overview_camera(tree.bboxes[0], engine.scale), (64, 48))
    assert frame.stats["patches"] > 0 and frame.stats["triangles"] == 0
    assert frame.stats["empty"] is True and not frame.image[..., 3].any()


# -- field of view -----------------------------------------------------------------------------


def test_render_fov_out_of_range_without_eye(folder, tmp_path):
    """--fov 0 without --eye was a ZeroDivisionError in the overview camera; every fov outside
    (0, 180) is one Error line."""
    for fov in ("0", "-10", "180", "nan"):
        png = tmp_path / "x.png"
        code, _, err = run("render", folder / "hills.zarr", "--fov", fov, "--out", png)
        assert_one_error_line(code, err, "fov must")
        assert not png.exists()


def test_camera_and_overview_validate_fov():
    """fov must lie in (0, 180) for Camera and for overview_camera (API)."""
    box = np.array([0.0, 0.0, 0.0, 100.0, 100.0, 10.0])
    for fov in (0.0, -1.0, 180.0, 200.0, float("nan"), float("inf")):
        with pytest.raises(InvalidParameterError, match="fov"):
            overview_camera(box, np.ones(3), fov=fov)
        with pytest.raises(InvalidParameterError, match="fov"):
            Camera.look_at((0, 0, 10), (1, 1, 0), fov=fov)


# -- outputs that cannot be written, checked before the work ------------------------------------


@pytest.fixture
def no_work(monkeypatch):
    """Make the expensive steps fail the test if they run: the output check must come first."""

    def forbidden(*args, **kwargs):
        raise AssertionError("the work ran before the output location was checked")

    monkeypatch.setattr("approxtree.cli.common._open", forbidden)
    monkeypatch.setattr("approxtree.tree.ApproximationTree.build", forbidden)
    monkeypatch.setattr("approxtree.tree.ApproximationTree.load", forbidden)
    monkeypatch.setattr("approxtree.datasets.sample_terrain", forbidden)


def output_commands(folder, out_file, out_dir):
    """(command line, its output) of every command that writes a file or a folder."""
    dem, tree = folder / "dem.npy", folder / "hills.zarr"
    return [
        (["build", dem, "--out", out_file("t.zarr.zip")], "t.zarr.zip"),
        (["mesh", dem, "--max-error", "1", "--out", out_file("m.ply")], "m.ply"),
        (["bake", dem, "--out", out_dir("tex")], "tex"),
        (["tiles", dem, "--format", "quantized-mesh", "--out", out_dir("qm")], "qm"),
        (["render", tree, "--out", out_file("r.png")], "r.png"),
        (["rd", dem, "--plot", out_file("rd.png")], "rd.png"),
        (["demo", "--out", out_file("d.zarr.zip")], "d.zarr.zip"),
        (["demo", "--out", folder / "unused.zarr", "--png", out_file("d.png")], "d.png"),
    ]


def test_output_under_a_regular_file_is_refused_before_the_work(folder, tmp_path, no_work):
    """An output path below a regular file cannot be written, even by root: every command
    refuses it before reading or building anything (was a late PermissionError/StoreError)."""
    blocker = tmp_path / "somefile"
    blocker.write_text("not a folder")
    for args, _ in output_commands(folder, lambda n: blocker / n, lambda n: blocker / n):
        code, _, err = run(*args)
        assert_one_error_line(code, err, "is a file, not a folder")
    assert blocker.read_text() == "not a folder"


def test_read_only_location_is_refused_before_the_work(folder, tmp_path, no_work, monkeypatch):
    """A folder on a read-only file system (creating a file there fails with EROFS, which
    binds root too; emulated here) is refused before the work, naming the reason."""

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr("approxtree.io.output_path.tempfile.mkstemp", read_only)
    out = tmp_path / "ro"
    out.mkdir()
    for args, _ in output_commands(folder, lambda n: out / n, lambda n: out / n):
        code, _, err = run(*args)
        assert_one_error_line(code, err, "not writable (Read-only file system)")
    assert list(out.iterdir()) == []


def in_read_only_mount(folder, command: str) -> list[str]:
    """The argv running ``command`` in a shell that sees a read-only tmpfs on ``folder`` (a
    private mount namespace through ``unshare -rm``: no privileges needed)."""
    return ["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o ro none '{folder}' && {command}"]


def test_real_read_only_mount_is_refused(folder, tmp_path):
    """On a real read-only mount (binding root too) build and bake end with one Error line
    that names the reason, from the installed entry point."""
    ro = tmp_path / "ro"
    ro.mkdir()
    probe = None
    if shutil.which("unshare") is not None:
        probe = subprocess.run(in_read_only_mount(ro, "echo mounted"), capture_output=True)
    if probe is None or probe.stdout.strip() != b"mounted":
        pytest.skip("cannot mount a read-only tmpfs here (unshare -rm not available)")
    exe = Path(sys.executable).with_name("approxtree")
    dem = folder / "dem.npy"
    for command in (
        f"'{exe}' build '{dem}' --out '{ro / 't.zarr.zip'}'",
        f"'{exe}' bake '{dem}' --out '{ro / 'tex'}'",
    ):
        proc = subprocess.run(
            in_read_only_mount(ro, command), capture_output=True, text=True, timeout=120
        )
        assert_one_error_line(proc.returncode, proc.stderr, "Read-only file system")


@pytest.mark.skipif(
    hasattr(os, "geteuid") and os.geteuid() == 0,
    reason="root writes into a mode 0500 folder: permission bits cannot make it unwritable",
)
def test_folder_without_write_permission_is_refused_before_the_work(folder, tmp_path, no_work):
    """A folder of mode 0500 (no write bit) is refused before the work."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        for args, _ in output_commands(folder, lambda n: locked / n, lambda n: locked / n):
            code, _, err = run(*args)
            assert_one_error_line(code, err, "not writable")
    finally:
        locked.chmod(0o700)


# -- bake into a folder whose parents do not exist ----------------------------------------------


def test_bake_refuses_a_folder_whose_parents_do_not_exist(folder, tmp_path):
    """bake created missing parents while every other command refused them; now it refuses
    too (CLI and API), and creates nothing."""
    from approxtree.textures.bake import bake

    target = tmp_path / "missing" / "deeper" / "tex"
    code, _, err = run("bake", folder / "dem.npy", "--out", target)
    assert_one_error_line(code, err, "does not exist")
    with pytest.raises(StoreError, match="does not exist"):
        bake(Grid(hills()), target, gl=False)
    assert not (tmp_path / "missing").exists()
    # A new folder whose parent exists is fine.
    code, _, err = run("bake", folder / "dem.npy", "--out", tmp_path / "tex", "--no-gl")
    assert code == 0, err
    assert (tmp_path / "tex" / "pyramid.json").is_file()


# -- frames that show no terrain -----------------------------------------------------------------


def test_empty_frames_say_so_in_stats_and_a_warning(folder, tmp_path):
    """An eye under the ground and a frustum that misses the terrain were blank images with
    no word: the stats say empty with the reason, the API warns and the CLI prints one
    Warning line (exit 0, the image is still written)."""
    tree = ApproximationTree.load(folder / "hills.zarr")
    d = tree.terrain.domain
    cx, cy = d.center
    cases = {
        "below the terrain surface": ((cx, cy, 0.0), (cx + 5, cy, 0.0)),
        "No part of the terrain lies in the view frustum": ((cx, cy, 500.0), (cx, cy, 900.0)),
    }
    with Engine(tree) as engine:
        for words, (eye, target) in cases.items():
            # An ApproxTreeWarning, so the viewer and every CLI command print one Warning line.
            with pytest.warns(ApproxTreeWarning, match=words) as caught:
                frame = engine.render(Camera.look_at(eye, target), (48, 32))
            assert all(issubclass(w.category, EmptyFrameWarning) for w in caught)
            assert frame.stats["empty"] is True and words in frame.stats["warning"]
            assert not frame.image[..., 3].any()
        frame = engine.render(overview_camera(tree.bboxes[0], engine.scale), (48, 32))
        assert frame.stats["empty"] is False and frame.stats["warning"] is None
    for words, (eye, target) in cases.items():
        png = tmp_path / "empty.png"
        eye_arg = ",".join(map(str, eye))
        target_arg = ",".join(map(str, target))
        code, out, err = run(
            "render", folder / "hills.zarr", "--eye", eye_arg, "--target", target_arg,
            "--size", "48x32", "--background", "transparent", "--out", png, "--json",
        )  # fmt: skip
        assert code == 0, err
        stats = json.loads(out)
        assert stats["empty"] is True and words in stats["warning"]
        assert err.startswith("Warning: ") and words in err and len(err.splitlines()) == 1
        assert not (np.asarray(Image.open(png))[..., 3] > 0).any()


# -- one Error line for small slips -------------------------------------------------------------


def test_usage_errors_are_one_error_line(folder):
    """An unknown option, a missing argument or option and a bad choice are one ``Error:``
    line naming the help to read, exit 2 (click printed usage, hint and error: three lines);
    --help still prints the whole help, exit 0."""
    tree = folder / "hills.zarr"
    for args, words in (
        (["render", tree, "--bogus"], "No such option '--bogus'"),
        (["render"], "Missing argument 'TREE_FILE'"),
        (["tiles", tree, "--format", "3dtiles"], "Missing option '--out'"),
        (["tiles", tree, "--out", "x", "--format", "kml"], "'kml' is not one of"),
        (["nosuch"], "No such command 'nosuch'"),
        (["--bogus"], "No such option '--bogus'"),
    ):
        code, _, err = run(*args)
        assert_one_error_line(code, err, words)
        assert "--help" in err
    code, out, _ = run("render", "--help")
    assert code == 0 and out.startswith("Usage: ") and "render [OPTIONS]" in out
    assert "--overwrite" in out


def test_camera_coordinates_are_checked_before_any_warning(folder, tmp_path):
    """--eye 1e300,… and an infinite --target are one Error line (numpy's overflow warnings
    came first, then a near/far error)."""
    for option, value in (("--eye", "1e300,1,1"), ("--target", "inf,0,0"), ("--eye", "0,nan,5")):
        code, _, err = run(
            "render", folder / "hills.zarr", option, value, "--out", tmp_path / "r.png"
        )
        assert_one_error_line(code, err, "finite coordinates")
        assert "Warning" not in err
    assert not (tmp_path / "r.png").exists()


def test_bake_refuses_an_infinite_or_non_positive_z_factor(folder, tmp_path):
    """--z-factor inf (exit 0 with a numpy RuntimeWarning and a black texture), nan, 0 and −1
    are one Error line; nothing is written."""
    for z in ("inf", "nan", "0", "-1"):
        code, _, err = run(
            "bake", folder / "dem.npy", f"--z-factor={z}", "--no-gl", "--out", tmp_path / "t"
        )
        assert_one_error_line(code, err, "z_factor (--z-factor) must be a finite number > 0")
    assert not (tmp_path / "t").exists()


def test_an_unknown_crs_is_one_line_without_gdal_noise(tmp_path):
    """`fractal --crs EPSG:999999` from the installed program prints our one Error line only
    (GDAL printed a raw "ERROR 1: PROJ" line before it)."""
    exe = Path(sys.executable).with_name("approxtree")
    proc = subprocess.run(
        [exe, "fractal", tmp_path / "f.tif", "--size", "64", "--crs", "EPSG:999999"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert_one_error_line(proc.returncode, proc.stderr, "Unknown CRS 'EPSG:999999'")
    assert os.listdir(tmp_path) == []


def test_render_writes_the_format_its_extension_names(folder, tmp_path):
    """--out r.jpg is a JPEG (it was a PNG named .jpg), opaque RGB composited on the
    background; r.png is an RGBA PNG; another extension is refused before the work."""
    tree = folder / "hills.zarr"
    for name, fmt, mode in (
        ("r.jpg", "JPEG", "RGB"),
        ("r.jpeg", "JPEG", "RGB"),
        ("r.png", "PNG", "RGBA"),
    ):
        code, _, err = run("render", tree, "--out", tmp_path / name, "--size", "64x48")
        assert code == 0, err
        with Image.open(tmp_path / name) as im:
            assert (im.format, im.mode, im.size) == (fmt, mode, (64, 48))
    code, _, err = run("render", tree, "--out", tmp_path / "r.gif")
    assert_one_error_line(code, err, "unknown extension '.gif'")
    assert not (tmp_path / "r.gif").exists()
