"""Nothing the user had is lost: outputs replace only approxtree's own earlier outputs (or
anything but a link with --overwrite), never through a symbolic link, and reading a raster
writes nothing beside it."""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner

from approxtree.cli import main
from approxtree.errors import StoreError


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def assert_one_error_line(code: int, stderr: str, words: str) -> None:
    assert code == 2, stderr
    assert stderr.startswith("Error: ") and words in stderr, stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` by relative path, with its bytes."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A small georeferenced DEM (dem.tif, 40 × 48 cells in EPSG:4326) and its tree store."""
    folder = tmp_path_factory.mktemp("noloss")
    y, x = np.mgrid[0:40, 0:48]
    z = (200 + 40 * np.sin(x / 5) + 25 * np.cos(y / 4)).astype(np.float32)
    profile = {"driver": "GTiff", "width": 48, "height": 40, "count": 1, "dtype": "float32"}
    transform = Affine(0.001, 0, 6.0, 0, -0.001, 49.6)
    with rasterio.open(
        folder / "dem.tif", "w", crs="EPSG:4326", transform=transform, **profile
    ) as ds:
        ds.write(z, 1)
    code, _, err = run("build", folder / "dem.tif", "--out", folder / "tree.zarr", "-q")
    assert code == 0, err
    return folder


def user_folder(path: Path) -> dict[str, bytes]:
    """Put a user's notes.txt and mydata/keep.txt into ``path``; returns what is there."""
    (path / "mydata").mkdir(parents=True, exist_ok=True)
    (path / "notes.txt").write_text("my notes")
    (path / "mydata" / "keep.txt").write_text("keep me")
    return snapshot(path)


# -- folders ---------------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["3dtiles", "quantized-mesh"])
def test_tiles_keeps_a_users_files_in_an_earlier_tileset_folder(made, tmp_path, fmt):
    """A tileset folder holding a user's files besides tileset.json / layer.json is refused
    with one Error line naming them, everything kept (tiles emptied the folder, exit 0);
    --overwrite replaces it; a folder of tiles only is replaced without a word."""
    out = tmp_path / "mine"
    tiles = ("tiles", made / "tree.zarr", "--out", out, "--format", fmt)
    code, _, err = run(*tiles)
    assert code == 0, err
    before = user_folder(out)
    code, _, err = run(*tiles)
    assert_one_error_line(code, err, "mydata/keep.txt, notes.txt")
    assert snapshot(out) == before
    code, _, err = run(*tiles, "--overwrite")
    assert code == 0, err
    assert not (out / "notes.txt").exists() and not (out / "mydata").exists()
    code, _, err = run(*tiles)
    assert code == 0, err


@pytest.mark.parametrize("fmt", ["3dtiles", "quantized-mesh"])
def test_tiles_never_empties_the_target_of_a_symlinked_out(made, tmp_path, fmt):
    """--out naming a symbolic link is refused, with or without --overwrite, and the folder
    it points to keeps every file (its realpath was swapped out and deleted)."""
    real = tmp_path / "real"
    code, _, err = run("tiles", made / "tree.zarr", "--out", real, "--format", fmt)
    assert code == 0, err
    before = snapshot(real)
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    for extra in ((), ("--overwrite",)):
        code, _, err = run(
            "tiles", made / "tree.zarr", "--out", tmp_path / "link", "--format", fmt, *extra
        )
        assert_one_error_line(code, err, "symbolic link")
    assert snapshot(real) == before and (tmp_path / "link").is_symlink()


def test_build_and_bake_keep_a_users_folder(made, tmp_path):
    """build --out and bake --out naming a user's folder are refused before any work (build
    replaced the folder, deleting its files); a linked store folder is refused too."""
    mine = tmp_path / "mine"
    mine.mkdir()
    before = user_folder(mine)
    code, _, err = run("build", made / "dem.tif", "--out", mine, "-q")
    assert_one_error_line(code, err, "notes.txt")
    code, _, err = run("bake", made / "dem.tif", "--out", mine, "--no-gl", "-q")
    assert_one_error_line(code, err, "notes.txt")
    assert snapshot(mine) == before
    store = tmp_path / "store.zarr"
    shutil.copytree(made / "tree.zarr", store)
    (tmp_path / "link.zarr").symlink_to(store, target_is_directory=True)
    code, _, err = run("build", made / "dem.tif", "--out", tmp_path / "link.zarr", "-q")
    assert_one_error_line(code, err, "symbolic link")
    assert snapshot(store) == snapshot(made / "tree.zarr")
    # A user's file inside a store folder makes it the user's.
    (store / "notes.txt").write_text("mine")
    code, _, err = run("convert", made / "tree.zarr", store)
    assert_one_error_line(code, err, "notes.txt")
    # The store itself (approxtree's own) is rebuilt without a word.
    code, _, err = run("build", made / "dem.tif", "--out", made / "tree.zarr", "-q")
    assert code == 0, err


def test_the_api_refuses_to_replace_a_users_folder(made, tmp_path):
    """Saving a tree into a folder of the user's is a StoreError from the API too (the folder
    swap checks what it replaces), the folder untouched."""
    from approxtree.tree import load_tree

    mine = tmp_path / "mine"
    mine.mkdir()
    before = user_folder(mine)
    with pytest.raises(StoreError, match="did not write"):
        load_tree(made / "tree.zarr").save(mine)
    assert snapshot(mine) == before


# -- files -----------------------------------------------------------------------------------


def user_png(path: Path) -> None:
    from PIL import Image

    Image.new("RGB", (4, 4), (9, 9, 9)).save(path)


def file_outputs(made: Path, tmp_path: Path) -> list[tuple[list, Path, object]]:
    """(command line, its output file, how the user's file there is made) of every command
    that writes a file."""
    dem, tree = made / "dem.tif", made / "tree.zarr"

    def copy_dem(p):
        shutil.copy(dem, p)

    def text(p):
        p.write_text("ply\nformat ascii 1.0\nmine\n")

    def data(p):
        p.write_bytes(b"PK\x03\x04 my archive")

    o = tmp_path
    return [
        (["fractal", o / "f.tif", "--size", 64], o / "f.tif", copy_dem),
        (["build", dem, "--out", o / "t.zarr.zip", "-q"], o / "t.zarr.zip", data),
        (["convert", tree, o / "c.zarr.zip"], o / "c.zarr.zip", data),
        (["mesh", dem, "--max-error", 5, "--out", o / "m.ply", "-q"], o / "m.ply", text),
        (["mesh", dem, "--max-error", 5, "--out", o / "m.obj", "-q"], o / "m.obj", text),
        (["mesh", dem, "--max-error", 5, "--out", o / "m.glb", "-q"], o / "m.glb", data),
        (["render", tree, "--out", o / "r.png", "--size", "64x48"], o / "r.png", user_png),
        (["render", tree, "--out", o / "r.jpg", "--size", "64x48"], o / "r.jpg", user_png),
        (["rd", dem, "--rates", "8,16", "--plot", o / "rd.png", "-q"], o / "rd.png", user_png),
    ]


def test_every_command_refuses_to_replace_a_users_file_without_overwrite(made, tmp_path):
    """Each command that writes a file refuses one approxtree did not write (fractal replaced
    a DEM without a word); --overwrite replaces it, and the command's own output is then
    replaced without it (a rerun), recognised from the file's own mark."""
    for args, out, make in file_outputs(made, tmp_path):
        make(out)
        before = out.read_bytes()
        code, _, err = run(*args)
        assert_one_error_line(code, err, "--overwrite")
        assert out.read_bytes() == before, args
        code, _, err = run(*args, "--overwrite")
        assert code == 0, (args, err)
        assert out.read_bytes() != before
        code, _, err = run(*args)
        assert code == 0, (args, err)
    # Nothing but the outputs: no temp file left anywhere.
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_symlinked_output_file_is_refused(made, tmp_path):
    """An output naming a symbolic link is refused (with --overwrite too); the link and the
    DEM it points to stay."""
    dem = tmp_path / "dem.tif"
    shutil.copy(made / "dem.tif", dem)
    (tmp_path / "link.tif").symlink_to(dem)
    for extra in ((), ("--overwrite",)):
        code, _, err = run("fractal", tmp_path / "link.tif", "--size", 64, *extra)
        assert_one_error_line(code, err, "symbolic link")
    assert dem.read_bytes() == (made / "dem.tif").read_bytes()


def test_the_demo_runs_twice(tmp_path, monkeypatch):
    """The demo rewrites its own tree, pyramid and image on a second run."""
    monkeypatch.chdir(tmp_path)
    for _ in range(2):
        code, _, err = run("demo", "--out", "d.zarr", "--json")
        assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.png", "d.zarr", "d_textures"]


# -- reading writes nothing beside the data ----------------------------------------------------


def test_reads_write_no_gdal_side_file(made, tmp_path):
    """Within ``no_side_files`` a raster whose statistics GDAL computed leaves no .aux.xml
    (GDAL's PAM writes one otherwise), and only this thread's opens are affected."""
    from approxtree.io.gdal import no_side_files

    for name in ("a.tif", "b.tif"):
        shutil.copy(made / "dem.tif", tmp_path / name)
    with no_side_files(), rasterio.open(tmp_path / "a.tif") as ds:
        ds.stats(indexes=1, approx=False)
        # Another thread opening meanwhile keeps GDAL's default (PAM on).
        other = threading.Thread(target=_statistics, args=(tmp_path / "b.tif",))
        other.start()
        other.join()
    assert sorted(os.listdir(tmp_path)) == ["a.tif", "b.tif", "b.tif.aux.xml"]


def _statistics(path: Path) -> None:
    with rasterio.open(path) as ds:
        ds.stats(indexes=1, approx=False)


def test_approxtree_reads_leave_the_data_folder_as_it_was(made, tmp_path):
    """info, build, bake, mesh and tiles of a raster add no file beside it."""
    src = tmp_path / "data"
    src.mkdir()
    shutil.copy(made / "dem.tif", src / "dem.tif")
    dem = src / "dem.tif"
    for args in (
        ["info", dem],
        ["build", dem, "--out", tmp_path / "t.zarr", "-q"],
        ["bake", dem, "--out", tmp_path / "tex", "--no-gl", "-q"],
        ["mesh", dem, "--max-error", 5, "-q"],
        ["tiles", dem, "--out", tmp_path / "qm", "--format", "quantized-mesh"],
    ):
        code, _, err = run(*args)
        assert code == 0, (args, err)
    assert os.listdir(src) == ["dem.tif"]
