"""Bake the North Carolina textures and render one textured view of the terrain.

    python examples/bake_textures.py [--data ../shared/data/nc] [--out textures/nc]

Shows the cartographic case of the core paper (section 7): a topographic hillshade of the
30 m DEM blended (multiply) with the 10 m land-use raster and the streams drawn on top, baked
into a texture pyramid (offscreen with OpenGL where available), then the approximation tree
rendered with it unlit (decal mode) and lit, with and without ancestor texture sharing.
Outputs go to textures/ (git-ignored): the pyramid folder and nc_view.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image

import approxtree as at
from approxtree.render import Camera, Cut, Engine, Style
from approxtree.render.context import optional_context
from approxtree.textures.bake import bake

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "nc"))
    parser.add_argument("--out", default=str(ROOT / "textures" / "nc"))
    args = parser.parse_args()
    data, out = Path(args.data), Path(args.out)
    for name in ("elev_ned_30m.tif", "landuse_r.tif", "streams.shp"):
        if not (data / name).is_file():
            raise SystemExit(f"{data / name} is missing; see shared/data/README.md")

    # 1. Bake: land use · hillshade (multiply), streams over it, 10 m texels.
    # The hillshade is baked with OpenGL on a context of our own (numpy without one).
    dem = at.open_terrain(data / "elev_ned_30m.tif")
    with optional_context() as gl_context:
        result = bake(
            dem,
            out,
            shading="topographic",
            shading_options={"z_factor": 3.0},
            thematic=data / "landuse_r.tif",
            overlays=[data / "streams.shp"],
            blend="multiply",
            max_texture_size=1024,
            context=gl_context,
        )
    print("baked", result.figures())

    # 2. Render one oblique view from the south-west, textured.
    tree = at.ApproximationTree.build(dem, epsilon=1.0)
    c = dem.domain.center
    camera = Camera.look_at((c[0] - 4000, c[1] - 9000, 3500), (c[0], c[1], 80.0), fov=50)
    with Engine(tree, textures=result.pyramid) as engine:
        frame = engine.render(camera, (1280, 720), Cut(1.0, 2.0), style=Style(lighting=False))
        alone = engine.render(camera, (1280, 720), Cut(1.0, 2.0, share_textures=False))
    for name, f in (("shared", frame), ("own patches", alone)):
        s = f.stats
        print(
            f"{name:>12}: {s['patches']} patches, {s['texture_patches']} texture patches, "
            f"{s['texture_switches']} switches, max γ {s['max_gamma']:.2f}, "
            f"draw {s['draw_ms']:.1f} ms"
        )
    png = out.parent / "nc_view.png"
    Image.fromarray(frame.image, mode="RGBA").save(png)
    print("wrote", png)


if __name__ == "__main__":
    main()
