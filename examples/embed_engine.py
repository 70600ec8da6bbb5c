"""Embed the engine in a host program that owns its moderngl context and framebuffer.

The host creates the context (here a headless EGL one; a window toolkit's context works the
same way), its own framebuffer with a colour and a depth attachment, and binds it. The
Engine, given ``context=ctx``, draws the terrain into whatever framebuffer the host has
bound, leaves the host's state as it found it, and frees only its own GPU objects on
release(). The host then draws its own overlay (a red marker) and reads its pixels.

    python examples/embed_engine.py [--out embed.png]
"""

from __future__ import annotations

import argparse

import moderngl
import numpy as np
from PIL import Image

from approxtree import ApproximationTree
from approxtree.datasets import sample_terrain
from approxtree.render import Cut, Engine, overview_camera

WIDTH, HEIGHT = 800, 450


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="embed.png", help="PNG the host writes")
    args = ap.parse_args()

    # The host's own context and framebuffer.
    ctx = moderngl.create_standalone_context(backend="egl")
    color = ctx.renderbuffer((WIDTH, HEIGHT), 4)
    depth = ctx.depth_renderbuffer((WIDTH, HEIGHT))
    fbo = ctx.framebuffer(color_attachments=[color], depth_attachment=depth)

    tree = ApproximationTree.build(sample_terrain(), epsilon=1.0, progress=False)
    engine = Engine(tree, context=ctx)
    camera = overview_camera(tree.bboxes[0], engine.scale)

    # Host: bind its framebuffer; the engine draws into it.
    fbo.use()
    frame = engine.render(camera, (WIDTH, HEIGHT), Cut(alpha=1.0, gamma=2.0))
    print({k: frame.stats[k] for k in ("patches", "triangles", "draw_ms")})

    # Host: its own drawing on top (a red square in the centre, scissored clear).
    ctx.scissor = (WIDTH // 2 - 5, HEIGHT // 2 - 5, 10, 10)
    fbo.clear(1.0, 0.0, 0.0, 1.0)
    ctx.scissor = None

    pixels = np.frombuffer(fbo.read(components=4), dtype=np.uint8).reshape(HEIGHT, WIDTH, 4)
    Image.fromarray(pixels[::-1].copy(), mode="RGBA").save(args.out)
    print(f"host wrote {args.out}: terrain covers {(pixels[..., 3] > 0).mean():.0%} of it")

    # The engine frees its own objects; the host frees its own.
    engine.release()
    for obj in (fbo, color, depth):
        obj.release()
    ctx.release()


if __name__ == "__main__":
    main()
