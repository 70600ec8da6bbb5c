"""Progress bars: the library reports real totals through a callback, the CLI turns them into
a tqdm bar on a terminal only (pseudo-terminal here), silent with -q or off a terminal."""

from __future__ import annotations

import fcntl
import io
import json
import os
import pty
import re
import struct
import subprocess
import sys
import termios
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from approxtree.geometry import Grid
from approxtree.progress import progress_bar
from approxtree.textures.bake import bake
from approxtree.tree import ApproximationTree

# "n/total" counts of the bar; an ETA would show as "<" inside the brackets.
COUNTS = re.compile(r"(\d+)/(\d+) (\w+) \[")


def hills(n: int = 200) -> np.ndarray:
    y, x = np.mgrid[0:n, 0:n] / n
    return (40 * np.sin(6 * x) * np.cos(5 * y) + 15 * np.sin(23 * x * y)).astype(np.float32)


def write_dem(path: Path, n: int = 200) -> Path:
    z = hills(n)
    profile = {
        "driver": "GTiff",
        "width": n,
        "height": n,
        "count": 1,
        "dtype": "float32",
        "transform": Affine(10.0, 0, 500000.0, 0, -10.0, 4000000.0),
        "crs": "EPSG:32617",
    }
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)
    return path


def recorder() -> tuple[list[tuple[int, int]], object]:
    calls: list[tuple[int, int]] = []
    return calls, lambda done, total: calls.append((done, total))


def check_calls(calls: list[tuple[int, int]], total: int) -> None:
    """Counts never go back, the total never changes, the last report is the total."""
    assert calls, "no progress reported"
    assert {t for _, t in calls} == {total}
    done = [d for d, _ in calls]
    assert done == sorted(done) and done[0] == 0 and done[-1] == total


def test_build_reports_points_covered_up_to_the_total():
    grid = Grid(hills())
    calls, cb = recorder()
    ApproximationTree.build(grid, epsilon=0.5, max_points=17 * 17, progress=cb)
    check_calls(calls, grid.point_count)
    # Reported once a level is done: several intermediate counts, not a jump from 0 to done.
    assert len({d for d, _ in calls}) >= 3


def test_blocked_build_reports_blocks():
    grid = Grid(hills(256))
    calls, cb = recorder()
    ApproximationTree.build(grid, epsilon=0.5, max_points=17 * 17, block_size=64, progress=cb)
    total = calls[-1][1]
    assert total > 1
    check_calls(calls, total)
    assert [d for d, _ in calls] == list(range(total + 1))


def test_bake_reports_rows_of_every_level(tmp_path):
    grid = Grid(hills(300), Affine(10.0, 0, 0, 0, -10.0, 3000.0))
    calls, cb = recorder()
    result = bake(grid, tmp_path / "pyr", gl=False, max_texture_size=64, progress=cb)
    rows = sum(lv.height for lv in result.pyramid.levels)
    assert len(result.pyramid) >= 3
    check_calls(calls, rows)


def test_bar_ends_at_its_total_without_eta():
    out = io.StringIO()
    with progress_bar("work", unit="row", force=True, file=out) as report:
        for i in range(0, 1001, 250):
            report(i, 1000)
    text = out.getvalue()
    counts = COUNTS.findall(text)
    assert counts and counts[-1] == ("1000", "1000", "row")
    assert all(t == "1000" for _, t, _ in counts)
    assert "<" not in text and "?" not in text


def test_quiet_bar_prints_nothing():
    out = io.StringIO()
    with progress_bar("work", quiet=True, force=True, file=out) as report:
        report(0, 10)
        report(10, 10)
    assert out.getvalue() == ""


def run_on_terminal(args: list[str], cwd: Path) -> tuple[int, str, str]:
    """Run ``approxtree ARGS`` with stderr on a pseudo-terminal (120 columns), stdout a pipe."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    proc = subprocess.Popen(
        [sys.executable, "-m", "approxtree", *args],
        stdout=subprocess.PIPE,
        stderr=slave,
        cwd=cwd,
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:
            break
        if not data:
            break
        chunks.append(data)
    out = proc.stdout.read().decode()  # type: ignore[union-attr]
    proc.wait()
    os.close(master)
    return proc.returncode, out, b"".join(chunks).decode(errors="replace")


@pytest.mark.parametrize(
    ("command", "unit"),
    [
        (["build", "dem.tif", "--out", "t.zarr", "--epsilon", "0.5"], "point"),
        (["bake", "dem.tif", "--out", "pyr", "--no-gl", "--max-texture-size", "64"], "row"),
        (["mesh", "dem.tif", "--max-points", "300"], "stage"),
        (["rd", "dem.tif", "--rates", "64,128", "--methods", "uniform,tin"], "stage"),
    ],
    ids=["build", "bake", "mesh", "rd"],
)
def test_cli_bar_on_a_terminal_reaches_its_total(tmp_path, command, unit):
    write_dem(tmp_path / "dem.tif")
    rc, out, err = run_on_terminal([*command, "--json"], tmp_path)
    assert rc == 0, err
    json.loads(out)  # stdout stays one JSON object
    counts = COUNTS.findall(err)
    assert counts, err
    done, total, shown_unit = counts[-1]
    assert done == total and int(total) > 1 and shown_unit == unit
    assert {t for _, t, _ in counts} == {total}  # the total never changes
    assert "<" not in err and "?" not in err  # no ETA


def test_cli_is_quiet_with_q_or_off_a_terminal(tmp_path):
    write_dem(tmp_path / "dem.tif")
    rc, out, err = run_on_terminal(
        ["build", "dem.tif", "--out", "a.zarr", "-q", "--json"], tmp_path
    )
    assert rc == 0 and json.loads(out)["nodes"] > 1
    assert err.strip() == ""
    proc = subprocess.run(
        [sys.executable, "-m", "approxtree", "build", "dem.tif", "--out", "b.zarr", "--json"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0 and json.loads(proc.stdout)["nodes"] > 1
    assert proc.stderr == ""


def test_no_bar_off_a_terminal_imports_no_tqdm():
    """Off a terminal (or quiet) nothing is drawn, and tqdm is not even imported (a bake's
    start-up); on a terminal the bar still comes (see the tests above)."""
    code = (
        "import io, sys\n"
        "from approxtree.progress import progress_bar\n"
        "for quiet in (False, True):\n"
        "    with progress_bar('x', unit='row', quiet=quiet, file=io.StringIO()) as report:\n"
        "        report(1, 2); report(2, 2)\n"
        "print('tqdm' in sys.modules)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "False"
