"""A full disk: every command ends with one Error line saying so (exit 2), leaves no temp
file or folder, and the output it would have replaced stays as it was.

The disk is a small tmpfs (root only; skipped with the reason otherwise), filled up to the last
page after the first, good output is written. Commands run as the installed program, so what
Python prints at exit (asyncio's "Task was destroyed", tracebacks) is seen too.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner

from approxtree.cli import main
from approxtree.cli.compile_notice import NOTICE

EXE = Path(sys.executable).with_name("approxtree")


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A small georeferenced DEM (dem.tif, 64 × 72 cells in EPSG:4326) and its tree store."""
    folder = tmp_path_factory.mktemp("fulldisk")
    y, x = np.mgrid[0:64, 0:72]
    z = (300 + 60 * np.sin(x / 6) + 30 * np.cos(y / 5)).astype(np.float32)
    profile = {"driver": "GTiff", "width": 72, "height": 64, "count": 1, "dtype": "float32"}
    transform = Affine(0.001, 0, 6.0, 0, -0.001, 49.6)
    with rasterio.open(
        folder / "dem.tif", "w", crs="EPSG:4326", transform=transform, **profile
    ) as ds:
        ds.write(z, 1)
    program(["build", folder / "dem.tif", "--out", folder / "tree.zarr", "-q"], check=True)
    return folder


def program(args: list, check: bool = False) -> subprocess.CompletedProcess:
    """The installed ``approxtree`` run with ``args``."""
    proc = subprocess.run([str(EXE), *map(str, args)], capture_output=True, text=True, timeout=300)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture
def disk(tmp_path):
    """A 4 MiB tmpfs, unmounted at the end whatever happens."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    folder = tmp_path / "disk"
    folder.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(folder)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path) -> None:
    """Take every free byte of ``folder``'s disk (tmpfs: whole pages)."""
    free = shutil.disk_usage(folder).free
    with open(folder / "filler", "wb") as f:
        f.write(b"\0" * free)
    assert shutil.disk_usage(folder).free < 4096


def snapshot(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "filler"
    }


#: (name, command line with {d} the disk, {dem} the DEM, {tree} the store, the output's name).
COMMANDS = [
    ("build store", ["build", "{dem}", "--out", "{d}/t.zarr", "-q"], "t.zarr"),
    ("build zip", ["build", "{dem}", "--out", "{d}/t.zarr.zip", "-q"], "t.zarr.zip"),
    ("convert", ["convert", "{tree}", "{d}/c.zarr"], "c.zarr"),
    ("render", ["render", "{tree}", "--out", "{d}/r.png", "--size", "320x240"], "r.png"),
    ("render jpeg", ["render", "{tree}", "--out", "{d}/r.jpg", "--size", "320x240"], "r.jpg"),
    ("bake", ["bake", "{dem}", "--out", "{d}/tex", "--no-gl", "-q"], "tex"),
    ("bake gl", ["bake", "{tree}", "--out", "{d}/tex", "-q"], "tex"),
    ("mesh ply", ["mesh", "{dem}", "--max-error", "0.5", "--out", "{d}/m.ply", "-q"], "m.ply"),
    ("mesh glb", ["mesh", "{dem}", "--max-error", "0.5", "--out", "{d}/m.glb", "-q"], "m.glb"),
    ("tiles 3d", ["tiles", "{tree}", "--out", "{d}/t3", "--format", "3dtiles"], "t3"),
    ("tiles qm", ["tiles", "{tree}", "--out", "{d}/qm", "--format", "quantized-mesh"], "qm"),
    ("fractal", ["fractal", "{d}/f.tif", "--size", "600"], "f.tif"),
]


@pytest.mark.parametrize(("name", "args", "out"), COMMANDS, ids=[c[0] for c in COMMANDS])
def test_a_full_disk_is_one_error_line_and_the_old_output_stays(made, disk, name, args, out):
    """With the disk full, the command rewriting its earlier output prints one Error line
    saying the disk is full (render, bake, tiles, mesh, fractal printed OSError tracebacks,
    fractal even exited 0 with a broken file; build printed asyncio noise and left its temp
    store), exit 2, and leaves the old output as it was and no temp behind."""
    line = [a.format(d=disk, dem=made / "dem.tif", tree=made / "tree.zarr") for a in args]
    # The good output in-process (faster); the run on the full disk as the real program.
    good = CliRunner().invoke(main, line, catch_exceptions=False)
    assert good.exit_code == 0, good.stderr
    before = snapshot(disk)
    fill(disk)
    proc = program(line)
    assert proc.returncode == 2, proc.stderr
    # The compile notice, if the program compiled a kernel first, is not part of the error.
    err = "".join(x for x in proc.stderr.splitlines(keepends=True) if x.strip() != NOTICE)
    assert err.startswith("Error: ") and len(err.strip().splitlines()) == 1, proc.stderr
    assert "disk is full" in err or "free" in err, proc.stderr
    assert snapshot(disk) == before
    assert sorted(os.listdir(disk)) == sorted([out, "filler"])


def test_gdal_write_errors_are_caught(made, disk):
    """A GeoTIFF that the disk cannot hold (the room check passed, here by forcing it) is a
    StoreError from GDAL's logged write errors: no libtiff line on stderr, the old file in
    place, no temp (fractal exited 0 with `_tiffWriteProc: No space left on device`)."""
    old = disk / "f.tif"
    code = (
        "import sys\n"
        "import approxtree.io.tiled_geotiff as t\n"
        "t.estimated_bytes = lambda *args: 0\n"
        "from approxtree.cli import run\n"
        "sys.argv = ['approxtree', *sys.argv[1:]]\n"
        "run()\n"
    )

    def fractal(*args: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-c", code, "fractal", str(old), *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=300)

    assert fractal("--size", "64").returncode == 0
    before = old.read_bytes()
    for cog in ((), ("--cog",)):
        proc = fractal("--size", "2000", "--json", *cog)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.startswith("Error: ") and "disk is full" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert old.read_bytes() == before and os.listdir(disk) == ["f.tif"]


def test_fractal_says_what_it_takes_and_refuses_what_the_disk_cannot_hold(disk, tmp_path):
    """`fractal --size 100000` (2,401 blocks, ~20 GB) is refused at once on a disk without the
    room, saying how much it needs; an absurd size is refused whatever the disk; a size that
    fits is written, its size within the estimate."""
    from approxtree.datasets import FractalHeights
    from approxtree.io.tiled_geotiff import _creation_options, estimated_bytes

    proc = program(["fractal", disk / "big.tif", "--size", 100000])
    assert proc.returncode == 2 and "100,000 × 100,000 cells need about" in proc.stderr
    assert "GB" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert os.listdir(disk) == []
    proc = program(["fractal", disk / "big.tif", "--size", 3_000_000_000])
    assert proc.returncode == 2 and "at most" in proc.stderr, proc.stderr
    # The estimate holds the file it is made for (and is not far above it).
    out = tmp_path / "f.tif"
    program(["fractal", out, "--size", 1500, "--json"], check=True)
    source = FractalHeights((1500, 1500), hurst=0.9, relief=500.0)
    estimate = estimated_bytes(source, _creation_options("deflate", np.float32), cog=False)
    assert out.stat().st_size <= estimate <= 1.5 * out.stat().st_size
