"""Helpers of the tests that check where texture colours land: the pixel at a point of written
imagery tiles, and the viewer's keyframes of a scripted flight."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from approxtree.tiles.schemes import scheme_named


def pixel_at(folder: Path, lon: float, lat: float, z: int) -> np.ndarray | None:
    """(4,) uint8 RGBA pixel at (lon, lat) of the geographic imagery tile of zoom z holding it,
    in the written folder (None when no tile holds it)."""
    scheme = scheme_named("geographic")
    for path in (Path(folder) / str(z)).glob("*/*.png"):
        x, y = int(path.parent.name), int(path.stem)
        west, south, east, north = scheme.bounds(z, x, y)
        if west <= lon < east and south <= lat < north:
            image = np.asarray(Image.open(path).convert("RGBA"))
            size = image.shape[0]
            col = int((lon - west) / (east - west) * size)
            row = int((north - lat) / (north - south) * size)
            return image[row, col]
    return None


def view_keyframes(cwd: Path, args: list[str], script: list[dict]) -> list[np.ndarray]:
    """The (120, 160, 4) keyframes ``approxtree view ARGS`` saves flying ``script`` (a list of
    {"eye", "target", "frames"}) in a window of a private Xvfb display, flat-lit, every patch
    uploaded at once; skips when Xvfb is missing."""
    from approxtree.viewer.xvfb import virtual_display

    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    (cwd / "path.json").write_text(json.dumps(script))
    args = [*args, "--script", "path.json", "--screenshots", "shots", "--size", "160x120"]
    args += ["--max-uploads", "0", "--lighting", "off"]
    with virtual_display("640x480x24") as display:
        result = subprocess.run(
            [sys.executable, "-m", "approxtree", *args],
            cwd=cwd,
            env=dict(os.environ, DISPLAY=display),
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert result.returncode == 0, result.stderr
    return [
        np.asarray(Image.open(cwd / "shots" / f"keyframe_{i:03d}.png")) for i in range(len(script))
    ]
