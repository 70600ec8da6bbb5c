"""The command line keeps its own conventions (issue 27, section 3): every command that shows
progress takes -q, a bad --palette names every kind of palette accepted, stats keys say what
they count, line overlays are named for what they are."""

from __future__ import annotations

import fcntl
import inspect
import os
import pty
import struct
import subprocess
import sys
import termios
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import data_file

from approxtree.cli import _COMMANDS, main

REPO = Path(__file__).resolve().parents[1]


def run(*args: object) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI run in-process."""
    result = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.stdout, result.stderr


def _shows_progress(name: str) -> bool:
    """Whether a command's module (or the helper it hands its work to) shows progress."""
    import importlib

    module = importlib.import_module(f"approxtree.cli.{_COMMANDS[name][0]}")
    source = inspect.getsource(module)
    if name == "tiles":
        source += inspect.getsource(importlib.import_module("approxtree.cli.web_tiles"))
    return any(word in source for word in ("progress_bar", "progress=", "_tree_of("))


def test_every_command_showing_progress_takes_quiet():
    """Each command that shows a bar (its own or its in-memory build's) has -q/--quiet."""
    showing = [name for name in _COMMANDS if _shows_progress(name)]
    assert {"build", "bake", "mesh", "rd", "fractal", "render", "tiles", "demo", "view"} <= set(
        showing
    )
    for name in showing:
        options = {o for p in main.get_command(None, name).params for o in p.opts}  # type: ignore[union-attr]
        assert {"-q", "--quiet"} <= options, name


def _stderr_on_terminal(*args: str) -> tuple[int, str]:
    """(exit code, stderr) of the CLI in a subprocess whose stderr is a pseudo-terminal."""
    master, slave = pty.openpty()
    # A terminal of 80 columns (a fresh pty has 0: tqdm would draw an empty bar).
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "approxtree", *args],
        stdout=subprocess.DEVNULL,
        stderr=slave,
        env=env,
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    return proc.wait(timeout=600), b"".join(chunks).decode(errors="replace")


def test_fractal_bar_on_a_terminal_and_none_with_quiet(tmp_path):
    """fractal shows its bar on a terminal; with -q stderr stays empty."""
    args = ["fractal", "--size", "512", "--block", "512", "--workers", "1"]
    code, err = _stderr_on_terminal(*args, str(tmp_path / "a.tif"))
    assert code == 0 and "%|" in err
    code, err = _stderr_on_terminal(*args, str(tmp_path / "b.tif"), "-q")
    assert code == 0 and err == ""


@pytest.mark.parametrize("command", ["render", "tiles", "fractal"])
def test_quiet_errors_stay_one_line(command, tmp_path):
    """-q is accepted by render, tiles and fractal, and an error is still one Error: line."""
    missing = tmp_path / "missing.tif"
    args = {
        "render": ["render", missing, "--out", tmp_path / "x.png", "-q"],
        "tiles": ["tiles", missing, "--out", tmp_path / "t", "--format", "3dtiles", "-q"],
        "fractal": ["fractal", tmp_path / "f.tif", "--size", "0", "-q"],
    }[command]
    code, _, err = run(*args)
    assert code == 2
    assert err.startswith("Error: ") and err.count("\n") == 1, err


def _names_every_kind(message: str) -> None:
    """The hypsometric palettes, the legends, colour files and colormaps are all named."""
    from approxtree.textures.palettes import PALETTES
    from approxtree.textures.thematic import LEGENDS

    for name in [*PALETTES, *LEGENDS, "colour file", "matplotlib colormap"]:
        assert name in message, (name, message)


def test_render_bad_palette_names_every_kind(tmp_path):
    """render --palette nonsense: one Error line naming every kind of palette accepted."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.zeros((8, 8), dtype=np.float32))
    code, _, err = run("render", dem, "--out", tmp_path / "x.png", "--palette", "nonsense")
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("Error: Unknown palette 'nonsense'")
    _names_every_kind(err)


@pytest.mark.parametrize("palette", ["nonsense", "relief"])
def test_bake_bad_palette_names_every_kind(tmp_path, palette):
    """bake --thematic R --palette nonsense (or a hypsometric name): one Error line naming
    every kind, before the terrain is read."""
    raster = tmp_path / "classes.tif"
    raster.write_bytes(b"")
    code, _, err = run(
        "bake", tmp_path / "none.tif", "--out", tmp_path / "p", "--thematic", raster,
        "--palette", palette,
    )  # fmt: skip
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"Error: Unknown palette '{palette}' for the thematic raster")
    _names_every_kind(err)


def test_render_json_names_what_its_upload_count_counts(tmp_path):
    """render --json: gpu_uploads counts what upload_ms timed (> 0 for a first frame),
    paged_uploads is 0 for a frame that waits, and no bare "uploads" key is left."""
    import json

    dem = tmp_path / "dem.npy"
    z = np.add.outer(np.arange(33.0), np.arange(33.0)).astype(np.float32)
    np.save(dem, z)
    code, out, err = run("render", dem, "--out", tmp_path / "x.png", "--size", "64x48", "--json")
    assert code == 0, err
    stats = json.loads(out)
    assert "uploads" not in stats
    assert stats["gpu_uploads"] >= stats["patches"] > 0
    assert stats["paged_uploads"] == 0


def test_bake_lines_is_the_line_overlay_and_roads_its_alias(data_dir, tmp_path):
    """bake --lines draws the NC streams as a line overlay; --roads, its former name, bakes
    the same pyramid (its level 0 pixel for pixel)."""
    import json

    import rasterio

    dem = data_file(data_dir, "nc/elev_ned_30m.tif")
    streams = data_file(data_dir, "nc/streams.shp")
    levels = []
    for flag in ("--lines", "--roads"):
        out = tmp_path / flag.strip("-")
        code, text, err = run("bake", dem, flag, streams, "--out", out, "--no-gl", "-q", "--json")
        assert code == 0, err
        assert json.loads(text)["levels"] >= 1
        with rasterio.open(out / "level0.tif") as ds:
            levels.append(ds.read())
    assert (levels[0] == levels[1]).all()
    # The overlay colour (#2864c8) is drawn somewhere: the streams are in.
    r, g, b = levels[0][:3]
    assert ((r == 0x28) & (g == 0x64) & (b == 0xC8)).any()
