"""A re-bake on a full disk: one Error line, the pyramid as it was, no file of the re-bake
left (a tmpfs; root only, skipped otherwise, as tests/test_full_disk.py)."""

from __future__ import annotations

import os
import shutil

import numpy as np
from click.testing import CliRunner
from test_full_disk import NOTICE, disk, fill, made, program, snapshot  # noqa: F401
from test_update_store import write_patch

from approxtree.cli import main
from approxtree.io import read_grid


def test_rebake_on_a_full_disk_is_one_error_line_and_the_pyramid_stays(made, disk, tmp_path):  # noqa: F811
    """``update STORE PATCH --textures DIR`` with DIR's disk full: exit 2, one Error line
    saying so, DIR byte for byte as it was (no delta, no pyramid.json temp left)."""
    store = tmp_path / "tree.zarr"
    shutil.copytree(made / "tree.zarr", store)
    grid = read_grid(made / "dem.tif")
    patch = tmp_path / "pit.tif"
    write_patch(patch, grid, 20, 30, np.asarray(grid.heights)[20:40, 30:50] - 25.0)
    textures = disk / "tex"
    made_ok = CliRunner().invoke(
        main, ["bake", str(store), "--out", str(textures), "--no-gl", "-q"]
    )
    assert made_ok.exit_code == 0, made_ok.output
    before = snapshot(disk)
    fill(disk)
    proc = program(["update", store, patch, "--textures", textures])
    assert proc.returncode == 2, proc.stderr
    err = "".join(x for x in proc.stderr.splitlines(keepends=True) if x.strip() != NOTICE)
    assert err.startswith("Error: ") and len(err.strip().splitlines()) == 1, proc.stderr
    assert "disk is full" in err or "free" in err, proc.stderr
    assert snapshot(disk) == before
    assert sorted(os.listdir(disk)) == ["filler", "tex"]
    assert sorted(os.listdir(textures)) == sorted(p.rsplit("/", 1)[-1] for p in before)
