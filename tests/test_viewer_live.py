"""An open viewer shows `approxtree update` run by another process, without a restart."""

from __future__ import annotations

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
from test_live_follow import patch_file, store_and_pyramid

from approxtree.cli import main
from approxtree.viewer.xvfb import virtual_display

# Run in a process of its own (a glfw window on the private display): two frames of the
# viewer's step function (``render_frame``) around an update made through the CLI's code
# path by a child process, then a fresh viewer of the updated store at the same pose.
DRIVER = """
import json, subprocess, sys
from approxtree.render.cache_keys import MeshKey
from approxtree.tree.loading import load_tree
from approxtree.viewer.app import Viewer

store, tex, patch, out = sys.argv[1:]
common = dict(textures=[tex], size=(480, 270), gamma=0.5, max_uploads=0, lighting="off",
              bookmarks=out + "/bookmarks.json")
with Viewer(load_tree(store, verify=False), source=store, **common) as v:
    v.render_frame()
    v.driver.settle()  # the payloads loaded, the follower's first digests taken
    v.window.save_png(out + "/before.png")
    before = len(v.driver.engine.cache)
    update = [sys.executable, "-m", "approxtree", "update", store, patch, "--textures", tex]
    subprocess.run(update, check=True, capture_output=True)
    v.render_frame()
    v.window.save_png(out + "/after.png")
    figures = dict(v.driver.engine.update_figures)
    cam = v.nav.camera()
    messages = list(v.messages)
with Viewer(load_tree(store, verify=False), source=store, follow=False, **common) as fresh:
    fresh.nav.set_pose_world(cam.eye, cam.target)
    fresh.render_frame()
    fresh.window.save_png(out + "/fresh.png")
print(json.dumps({"before": before, "figures": figures, "messages": messages}))
"""


def test_open_viewer_shows_an_update_by_another_process(tmp_path: Path) -> None:
    """The frame after `approxtree update STORE PATCH --textures DIR` (another process)
    shows the edit, equals a fresh viewer's frame of the updated store pixel for pixel, and
    the Engine kept the unchanged nodes' meshes and texture patches."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian/Ubuntu: apt-get install -y xvfb)")
    store, tex, grid = store_and_pyramid(tmp_path)
    patch = patch_file(tmp_path, grid)
    with virtual_display("640x480x24") as display:
        result = subprocess.run(
            [sys.executable, "-c", DRIVER, str(store), str(tex), str(patch), str(tmp_path)],
            env=dict(os.environ, DISPLAY=display),
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    before, after, fresh = (
        np.asarray(Image.open(tmp_path / f"{name}.png")) for name in ("before", "after", "fresh")
    )
    assert not np.array_equal(before, after)
    np.testing.assert_array_equal(after, fresh)
    assert report["figures"]["gpu_kept"] > 0 and report["figures"]["gpu_dropped"] > 0
    assert report["figures"]["texture_gpu_kept"] > 0
    assert report["figures"]["texture_gpu_dropped"] > 0
    assert any(m.startswith("store updated:") for m in report["messages"])
    assert any(m.startswith("textures re-baked:") for m in report["messages"])


def test_view_cli_takes_no_follow(tmp_path: Path) -> None:
    """`approxtree view --help` offers --follow/--no-follow."""
    result = CliRunner().invoke(main, ["view", "--help"])
    assert result.exit_code == 0 and "--no-follow" in result.output
