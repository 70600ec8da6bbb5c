"""Cartographic viewer (core paper, section 7): fly over a terrain with its thematic layers.

Opens a window over a tree file or a DEM (built on the fly), with the texture pyramids given
by --textures as thematic layers (T toggles, TAB cycles). F1 in the window lists the keys:
orbit / pan / zoom-to-cursor with the mouse, fly mode (F, then WASD, Q/E, shift), α and γ
thresholds (1-4), wireframe (L), skirts (K), vertical exaggeration (PAGE_UP/DOWN), shading
(H), frustum freeze (C), screenshot (P), reset (R). All the reusable parts live in
approxtree.viewer; this file only reads the arguments.

    python examples/cartographic_viewer.py ../shared/data/nc/elev_ned_30m.tif \\
        [--textures textures/nc_landuse] [--script path.json --stats stats.jsonl]

Without a display, run it under a virtual X server: ``xvfb-run -a python ...``.
"""

from __future__ import annotations

import sys

from approxtree.cli import main

if __name__ == "__main__":
    sys.exit(main(["view", *sys.argv[1:]]))
