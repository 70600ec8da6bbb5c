"""
The viewer's map tools
======================

``approxtree view`` opens a glfw window over the Engine with a map interface drawn by imgui:
the cursor's coordinates (map CRS and longitude/latitude) and the elevation under it, a
legend (the elevation palette here; a land-cover legend with ``--legend``), a scale bar and
a north arrow that follow the camera, and a measure tool with an elevation profile.

The viewer is driven here by a camera script (``--script``: keyframes with actions) in a
virtual X display (Xvfb), and its screenshots are shown: the sample terrain from the south,
the same from the east (the north arrow turns), and straight down after two clicks of the
measure tool. The same works on a desktop with ``approxtree view demo.zarr``.
"""

# %%
import json
import os
import shutil
import subprocess
import sys

import numpy as np
from _gallery import WORK, placeholder, show
from PIL import Image

import approxtree as at
from approxtree.datasets import sample_terrain
from approxtree.render import display_scale
from approxtree.viewer.xvfb import virtual_display

tree = at.ApproximationTree.build(sample_terrain(), epsilon=1.0)
tree.save(WORK / "sample.zarr")

# Camera poses around the terrain's centre, in display units (metres; the sample DEM is in
# degrees), turned back into world coordinates for the script.
box = np.asarray(tree.bboxes[0]).reshape(2, 3)
centre = box.mean(axis=0)
centre[2] = box[0, 2]
scale = display_scale(tree.terrain)
span = float(np.max((box[1, :2] - box[0, :2]) * scale[:2]))


def pose(dx: float, dy: float, dz: float) -> list[float]:
    return (centre + np.array([dx, dy, dz]) * span / scale).tolist()


south, east, down, target = (
    pose(0, -1.1, 0.8),
    pose(1.1, 0, 0.8),
    pose(0, -0.02, 1.3),
    pose(0, 0, 0),
)
w, h = 800, 500
script = [
    {"eye": south, "target": target, "frames": 6},
    {"eye": south, "target": target, "frames": 1, "actions": [{"shot": "south.png"}]},
    {"eye": east, "target": target, "frames": 3},
    {"eye": east, "target": target, "frames": 1, "actions": [{"shot": "east.png"}]},
    {"eye": down, "target": target, "frames": 4, "keys": ["M"]},
    {"eye": down, "target": target, "frames": 1, "actions": [
        {"click": [w * 0.30, h * 0.35]},
        {"click": [w * 0.65, h * 0.70]},
        {"cursor": [w * 0.55, h * 0.45]},
        {"shot": "measure.png"},
    ]},
]  # fmt: skip
(WORK / "path.json").write_text(json.dumps(script))

# %%
# Run the viewer in a private Xvfb display; it exits after the last keyframe.
if shutil.which("Xvfb") is None:
    placeholder("Xvfb is not installed (apt-get install xvfb): no screenshots")
else:
    with virtual_display("1280x1024x24") as display:
        env = dict(os.environ, DISPLAY=display, XDG_CONFIG_HOME=str(WORK / "config"))
        command = [
            sys.executable, "-m", "approxtree", "view", "sample.zarr", "--script", "path.json",
            "--screenshots", "shots", "--size", f"{w}x{h}", "--max-uploads", "0",
        ]  # fmt: skip
        run = subprocess.run(command, cwd=WORK, env=env, capture_output=True, text=True)
    print(run.stdout, run.stderr)
    run.check_returncode()
    shots = [
        np.asarray(Image.open(WORK / "shots" / name))
        for name in ("south.png", "east.png", "measure.png")
    ]
    show(shots[:2], ["from the south: legend, scale bar, north arrow", "from the east"], 10)
    show(shots[2:], ["measure: distance and elevation profile"], 7)
