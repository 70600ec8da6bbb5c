"""Every terrain reader through every CLI command that takes a terrain.

info, build, render (of the built tree), mesh, bake, rd and view each run on a file of every
format: the real files of ../shared/data (GeoTIFF, ESRI ASCII grid, SRTM .hgt and .hgt.zip,
USGS DEM, SCAPE .stm, PGM, .npz, LAZ, quantized-mesh .terrain) and files made here (a small
LAS, Terrain-RGB, Terrarium and 16-bit grayscale PNGs). Each asserts the exit code and the
JSON figures. rd needs a grid: point clouds and TINs get a one-line error there.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import DATA_DIR
from PIL import Image

from approxtree import ApproximationTree
from approxtree.cli import main
from approxtree.io import open_terrain


@dataclass(frozen=True)
class Reader:
    """A terrain file and what ``info`` must report about it.

    file: path under ../shared/data, or "made:NAME" for a file the ``files`` fixture writes.
    options: reader options the format needs. points, z: valid data points and z range.
    epsilon: ε of the test build (large for the 1201² SRTM tiles, to stay quick).
    texel: bake texel size (None: the terrain's own cell size or point spacing).
    visible: the fitted default view shows terrain over a transparent background (every format;
    the .npz is read with --crs EPSG:4326: its degree cells without a CRS make it 0.33 × 0.29
    units wide and 840 tall, a needle no view shows, and the reader warns).
    """

    id: str
    file: str
    kind: str
    points: int
    z: tuple[float, float]
    options: tuple[str, ...] = ()
    epsilon: float = 5.0
    texel: float | None = None
    visible: bool = True

    @property
    def grid(self) -> bool:
        return self.kind == "grid"


READERS = [
    Reader("tif", "roads/lux_elev.tif", "grid", 4608, (141.0, 547.0)),
    Reader("asc", "edge/hugo_site.asc", "grid", 2152, (1660.0, 1711.0)),
    Reader("hgt", "srtm/N44W072.hgt", "grid", 1442401, (115.0, 1908.0), epsilon=50, texel=0.01),
    Reader(
        "hgt.zip",
        "srtm/N22W160v2.3a.hgt.zip",
        "grid",
        1438122,
        (-34.0, 1579.0),
        epsilon=50,
        texel=0.01,
    ),
    Reader("dem", "edge/SainteHelens.dem", "grid", 148885, (682.0, 2543.0), epsilon=20),
    Reader("stm", "scape/crater.stm", "grid", 154224, (1533.0, 2478.0), epsilon=20),
    Reader("pgm", "scape/crater.pgm", "grid", 154224, (1533.0, 2478.0), epsilon=20),
    Reader(
        "npz",
        "edge/jacksboro_fault_dem.npz",
        "grid",
        138632,
        (236.0, 1076.0),
        options=("--crs", "EPSG:4326"),
        epsilon=20,
    ),
    Reader("las", "made:small.las", "tinpointset", 400, (45.71, 61.25), epsilon=1.0),
    Reader(
        "laz",
        "lidar/autzen_trim.laz",
        "tinpointset",
        26107,
        (406.26, 434.06),
        options=("--ground-only",),
    ),
    Reader("terrain", "tin/9_533_383.terrain", "tin", 103, (206.34, 787.94), epsilon=2.0),
    Reader(
        "terrain-rgb",
        "made:terrain_rgb.png",
        "grid",
        1200,
        (449.1, 569.8),
        options=("--encoding", "terrain-rgb"),
        epsilon=1.0,
    ),
    Reader(
        "terrarium",
        "made:terrarium.png",
        "grid",
        1200,
        (449.08, 569.81),
        options=("--encoding", "terrarium"),
        epsilon=1.0,
    ),
    Reader(
        "png16",
        "made:gray16.png",
        "grid",
        1200,
        (449.1, 569.8),
        options=("--height-scale", "0.1"),
        epsilon=1.0,
    ),
]
POINT_SETS = [r for r in READERS if not r.grid]
BY_ID = {r.id: r for r in READERS}


def synthetic_heights() -> np.ndarray:
    """(30, 40) float64 heights 449..570 m: smooth hills on a slope."""
    y, x = np.mgrid[0:30, 0:40]
    return 500 + 40 * np.sin(x / 6) + 25 * np.cos(y / 5) + 0.5 * x


def write_small_las(path: Path) -> None:
    """400 scattered points over 100 m × 80 m, every fourth one not ground (class 1)."""
    import laspy

    rng = np.random.default_rng(0)
    n = 400
    x = rng.uniform(1000, 1100, n)
    y = rng.uniform(2000, 2080, n)
    z = 50 + 0.1 * (x - 1000) - 0.05 * (y - 2000) + 3 * np.sin(x / 10)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.01, 0.01, 0.01]
    header.offsets = [1000, 2000, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    classes = np.full(n, 2, dtype=np.uint8)
    classes[::4] = 1
    las.classification = classes
    las.write(path)


def write_pngs(folder: Path) -> None:
    """The synthetic heights as Terrain-RGB, Terrarium and 16-bit grayscale (0.1 m) PNGs."""
    h = synthetic_heights()
    v = np.round((h + 10000) * 10).astype(np.int64)
    rgb = np.stack([v // 65536, (v // 256) % 256, v % 256], axis=-1).astype(np.uint8)
    Image.fromarray(rgb, "RGB").save(folder / "terrain_rgb.png")
    t = h + 32768
    whole = np.floor(t).astype(np.int64)
    frac = np.floor((t - whole) * 256).astype(np.int64)
    rgb = np.stack([whole // 256, whole % 256, frac], axis=-1).astype(np.uint8)
    Image.fromarray(rgb, "RGB").save(folder / "terrarium.png")
    Image.fromarray(np.round(h * 10).astype(np.uint16)).save(folder / "gray16.png")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A folder holding the made files (small.las and the three PNG encodings)."""
    folder = tmp_path_factory.mktemp("made")
    write_small_las(folder / "small.las")
    write_pngs(folder)
    return folder


def path_of(reader: Reader, files: Path) -> Path:
    if reader.file.startswith("made:"):
        return files / reader.file.removeprefix("made:")
    path = DATA_DIR / reader.file
    if not path.exists():
        pytest.skip(f"real data file {path} is absent")
    return path


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def run_json(*args: object) -> dict:
    code, out, err = run(*args, "--json")
    assert code == 0, err
    return json.loads(out)


@pytest.fixture(scope="module")
def built(files, tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    """Per reader id: (tree file, build figures), built once through ``approxtree build``."""
    folder = tmp_path_factory.mktemp("trees")
    cache: dict[str, tuple[Path, dict]] = {}

    def get(reader: Reader) -> tuple[Path, dict]:
        if reader.id not in cache:
            out = folder / f"{reader.id}.zarr.zip"
            src = path_of(reader, files)
            figures = run_json(
                "build", src, *reader.options, "--epsilon", reader.epsilon, "--out", out
            )
            cache[reader.id] = (out, figures)
        return cache[reader.id]

    return get  # type: ignore[return-value]


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_info(reader, files):
    """info reports each format's kind, valid point count and z range."""
    figures = run_json("info", path_of(reader, files), *reader.options)
    assert figures["kind"] == reader.kind
    assert figures["points"] == reader.points
    assert figures["z_min"] == pytest.approx(reader.z[0], abs=0.01)
    assert figures["z_max"] == pytest.approx(reader.z[1], abs=0.01)
    assert (figures["width"] is not None) == reader.grid


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_build_then_render(reader, built, tmp_path):
    """build writes a tree within ε whose figures match the file; render draws it."""
    out, figures = built(reader)
    tree = ApproximationTree.load(out)
    assert figures["nodes"] == tree.stats()["nodes"] == len(tree)
    assert figures["bytes"] == out.stat().st_size
    assert figures["max_leaf_error"] <= reader.epsilon
    assert tree.terrain.point_count == reader.points
    png = tmp_path / "frame.png"
    # A transparent background: alpha then says where terrain was drawn (the sky is opaque).
    code, stdout, stderr = run(
        "render", out, "--out", png, "--size", "160x120", "--background", "transparent", "--json"
    )
    assert code == 0, stderr
    stats = json.loads(stdout)
    assert stats["triangles"] > 0 and stats["patches"] >= 1
    drawn = np.asarray(Image.open(png))[..., 3] > 0
    if reader.visible:
        assert stats["empty"] is False and stats["warning"] is None
        assert drawn.mean() > 0.05 and "Warning" not in stderr
    else:
        assert stats["empty"] is True and not drawn.any()
        assert stderr.startswith("Warning: No terrain pixel was drawn")


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_mesh(reader, files, tmp_path):
    """mesh --strategy tin (the default) meets its goal on every format and writes the mesh it
    reports: grids to an error of ε, point sets and TINs to a 64-vertex budget (their greedy
    insertion to an error is slow until the point-set kernel lands)."""
    import trimesh

    ply = tmp_path / "mesh.ply"
    goal = ("--max-error", reader.epsilon) if reader.grid else ("--max-points", 64)
    figures = run_json("mesh", path_of(reader, files), *reader.options, *goal, "--out", ply)
    assert figures["strategy"] == "tin"
    if reader.grid:
        assert 0 <= figures["max_error"] <= reader.epsilon
    else:
        assert 3 <= figures["vertices"] <= 64 and figures["max_error"] >= 0
    written = trimesh.load(ply, process=False)
    assert len(written.vertices) == figures["vertices"]
    assert len(written.faces) == figures["triangles"]


@pytest.mark.parametrize("reader", POINT_SETS, ids=lambda r: r.id)
def test_mesh_lattice_strategy_on_scattered_data_names_tin(reader, files):
    """A lattice strategy over points or triangles is one Error line that names --strategy tin."""
    code, _, err = run(
        "mesh", path_of(reader, files), *reader.options, "--strategy", "grid", "--max-points", 64
    )
    assert code == 2
    assert err.startswith("Error: ") and "--strategy tin" in err


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_bake(reader, files, tmp_path):
    """bake shades every format (point clouds and TINs rasterized) into a pyramid that covers
    the terrain's domain."""
    import rasterio

    folder = tmp_path / "tex"
    texel = ("--texel", reader.texel) if reader.texel else ()
    figures = run_json("bake", path_of(reader, files), *reader.options, *texel, "--out", folder)
    assert figures["layers"] == ["shading:topographic"]
    assert figures["levels"] >= 1 and (folder / "pyramid.json").is_file()
    options = {"encoding": reader.options[1]} if "--encoding" in reader.options else {}
    if "--height-scale" in reader.options:
        options["height_scale"] = float(reader.options[1])
    if "--ground-only" in reader.options:
        options["ground_only"] = True
    if "--crs" in reader.options:
        options["crs"] = reader.options[1]
    domain = open_terrain(path_of(reader, files), **options).domain
    with rasterio.open(folder / "level0.tif") as ds:
        b = ds.bounds
        tol = max(abs(ds.res[0]), abs(ds.res[1]))
        # The last band is alpha (grey + alpha for a shading).
        level0 = ds.read(ds.count)
    assert b.left <= domain.xmin + tol and b.right >= domain.xmax - tol
    assert b.bottom <= domain.ymin + tol and b.top >= domain.ymax - tol
    # Shading was drawn over the terrain: most texels are opaque.
    assert (level0 > 0).mean() > 0.3


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_rd(reader, files):
    """rd compares methods on every grid format; point clouds and TINs get one Error line."""
    args = ("rd", path_of(reader, files), *reader.options, "--size", 17, "--rates", "8,16")
    if reader.grid:
        figures = run_json(*args, "--methods", "uniform")
        assert figures["size"] == 17 and figures["rates"] == [8, 16]
        rows = figures["methods"]["uniform"]["rows"]
        assert [r["triangles"] for r in rows] == [8, 16]
    else:
        code, _, err = run(*args, "--methods", "uniform")
        assert code == 2
        assert err.startswith("Error: ") and "needs a raster grid" in err


# Runs each job's view command in-process, in a process of its own: glfw must not share a
# process with the EGL contexts the other tests make (the process dies when they meet).
VIEW_RUNNER = """
import json, sys
from click.testing import CliRunner
from approxtree.cli import main
jobs = json.load(open(sys.argv[1]))
results = {}
for job in jobs:
    r = CliRunner().invoke(main, job["args"])
    results[job["id"]] = {"exit_code": r.exit_code, "stderr": r.stderr, "error": repr(r.exception)}
json.dump(results, open(sys.argv[2], "w"))
"""


@pytest.fixture(scope="module")
def view_runs(files, tmp_path_factory) -> tuple[dict, Path]:
    """({reader id: exit code, stderr}, folder of the stats files) of ``approxtree view`` on
    every reader's file, 3 frames each, run under a private Xvfb display."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    from approxtree.viewer.xvfb import virtual_display

    folder = tmp_path_factory.mktemp("view")
    jobs = []
    for reader in READERS:
        path = DATA_DIR / reader.file
        if not reader.file.startswith("made:") and not path.exists():
            continue
        args = ["view", str(path_of(reader, files)), *reader.options]
        args += ["--epsilon", str(reader.epsilon), "--frames", "3", "--size", "96x64"]
        args += ["--stats", str(folder / f"{reader.id}.jsonl")]
        jobs.append({"id": reader.id, "args": args})
    (folder / "jobs.json").write_text(json.dumps(jobs))
    with virtual_display("640x480x24") as name:
        proc = subprocess.run(
            [sys.executable, "-c", VIEW_RUNNER, folder / "jobs.json", folder / "results.json"],
            env=dict(os.environ, DISPLAY=name),
            capture_output=True,
            text=True,
            timeout=900,
        )
    assert proc.returncode == 0, proc.stderr
    return json.loads((folder / "results.json").read_text()), folder


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.id)
def test_view(reader, files, view_runs):
    """view opens every format as a DEM (built at the reader's ε) and draws terrain in its
    first frames (headless, under Xvfb)."""
    path_of(reader, files)  # skips when the data file is absent
    results, folder = view_runs
    result = results[reader.id]
    assert result["exit_code"] == 0, (result["stderr"], result["error"])
    lines = [json.loads(s) for s in (folder / f"{reader.id}.jsonl").read_text().splitlines()]
    assert len(lines) == 3
    assert lines[-1]["triangles"] > 0 and lines[-1]["patches"] >= 1


def test_inapplicable_reader_option_given_explicitly_is_one_error_line(files):
    """A reader option the format does not take is refused, worded with the command's flag."""
    tile = path_of(BY_ID["terrain"], files)
    cases = [
        (["info", files / "small.las", "--nodata", "mask"], "--nodata does not apply"),
        (
            ["build", tile, "--nodata", "fill", "--out", files / "t.zarr"],
            "--nodata does not apply",
        ),
        (["mesh", files / "gray16.png", "--ground-only", "--max-points", 8], "--ground-only"),
        (["info", files / "small.las", "--height-scale", 2], "--height-scale does not apply"),
    ]
    for args, words in cases:
        code, _, err = run(*args)
        assert code == 2, args
        assert err.startswith("Error: ") and words in err, err
    assert not (files / "t.zarr").exists()


def test_explicit_reader_options_still_apply_to_their_format():
    """--nodata given explicitly still reaches a grid reader (fill leaves no nodata)."""
    path = path_of(BY_ID["asc"], Path())
    assert run_json("info", path, "--nodata", "mask")["nodata_count"] == 2028
    filled = run_json("info", path, "--nodata", "fill")
    assert filled["nodata_count"] == 0 and filled["points"] == 76 * 55


def test_cell_size_reaches_the_grid_readers(files):
    """--cell-size gives a grid without a georeference its cells (one number or DX,DY); it is
    refused for point clouds, and a value that is not one or two positive numbers is an error."""
    png = files / "gray16.png"
    scale = ("--height-scale", "0.1")
    assert run_json("info", png, *scale)["cell_size"] == [1.0, 1.0]
    assert run_json("info", png, *scale, "--cell-size", "30")["cell_size"] == [30.0, 30.0]
    assert run_json("info", png, *scale, "--cell-size", "30,20")["cell_size"] == [30.0, 20.0]
    code, _, err = run("info", files / "small.las", "--cell-size", "3")
    assert code == 2 and err.startswith("Error: ") and "--cell-size does not apply" in err
    for bad in ("x", "-3", "1,2,3", "nan"):
        code, _, err = run("info", png, *scale, "--cell-size", bad)
        assert code == 2 and "Invalid value for '--cell-size'" in err, (bad, err)


def test_reader_options_with_a_tree_file_are_refused(built, files, tmp_path):
    """Reader options choose how a terrain file is read; with a built tree they are an error
    (they used to be ignored silently)."""
    tree, _ = built(BY_ID["las"])
    for args in (
        ["bake", tree, "--out", tmp_path / "tex", "--nodata", "fill"],
        ["view", tree, "--ground-only", "--frames", 1],
    ):
        code, _, err = run(*args)
        assert code == 2, args
        assert err.startswith("Error: ") and "saved tree" in err
    assert not (tmp_path / "tex").exists()


def entry_point() -> str:
    """The installed ``approxtree`` console script next to this Python."""
    script = Path(sys.executable).with_name("approxtree")
    found = str(script) if script.exists() else shutil.which("approxtree")
    if found is None:
        pytest.skip("the approxtree console script is not installed (pip install -e .)")
    return found


def test_installed_entry_point_reads_point_clouds(files, tmp_path):
    """The installed ``approxtree`` script reads and builds a LAS file (a real process)."""
    exe = entry_point()
    src = files / "small.las"
    info = subprocess.run([exe, "info", src, "--json"], capture_output=True, text=True)
    assert info.returncode == 0, info.stderr
    assert json.loads(info.stdout)["points"] == 400
    out = tmp_path / "small.zarr"
    proc = subprocess.run(
        [exe, "build", src, "--ground-only", "--epsilon", "1", "--out", out, "--json"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["max_leaf_error"] <= 1.0
    assert ApproximationTree.load(out).terrain.point_count == 300


def test_rasterize_samples_h_t_on_a_lattice_over_the_domain(files):
    """bake shades a point cloud through rasterize: a lattice whose outer points lie on the
    domain's edges, heights equal to h_T there, nodata beyond the convex hull."""
    from approxtree.geometry.rasterize import mean_spacing, rasterize

    points = open_terrain(files / "small.las")
    grid = rasterize(points)
    d, g = points.domain, grid.domain
    assert (g.xmin, g.ymin, g.xmax, g.ymax) == pytest.approx((d.xmin, d.ymin, d.xmax, d.ymax))
    # About one lattice point per data point.
    assert abs(grid.cell_size[0] - mean_spacing(points)) < 0.1 * mean_spacing(points)
    xyz = grid.points()
    assert np.allclose(xyz[:, 2], points.height_at(xyz[:, 0], xyz[:, 1]))
    # Lattice points beyond the hull (the corners) are nodata.
    assert 0 < grid.nodata_count < 0.2 * grid.width * grid.height
    assert rasterize(grid) is grid
