"""A texture patch embedded in a mesh file: encoded image plus per-vertex texture coordinates.

For glTF (3D Tiles content, ``approxtree mesh --out x.glb``): the texture patch covering a
rectangle (textures/patch.py, as the renderer picks it) encoded as PNG (lossless, keeps
transparency beyond the texture's edge) or JPEG (smaller, opaque), and texture coordinates
u = (x − xmin) / width, v = (ymax − y) / height of the patch's extent: glTF's texture origin is
the image's top-left texel, and row 0 of a pyramid level is its north edge.
"""

from __future__ import annotations

import io

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.rect import Rect
from approxtree.textures.patch import TexturePatch
from approxtree.textures.pyramid import TexturePyramid

#: Texture encodings: name → (PIL format, MIME type).
IMAGE_FORMATS = {"png": ("PNG", "image/png"), "jpeg": ("JPEG", "image/jpeg")}


def embedded_texture(
    pyramid: TexturePyramid, rect: Rect, vertices: np.ndarray, image_format: str = "png"
) -> tuple[np.ndarray, bytes, str]:
    """(uvs (n, 2) float64, encoded image, MIME type) of the texture patch covering ``rect``
    for ``vertices`` (n, 3) world coordinates."""
    from PIL import Image

    if image_format not in IMAGE_FORMATS:
        raise InvalidParameterError(
            f"Unknown texture format {image_format!r}; use one of {', '.join(IMAGE_FORMATS)}."
        )
    patch = TexturePatch.for_rect(pyramid, rect)
    ext = patch.extent
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    uvs = np.column_stack([(v[:, 0] - ext.xmin) / ext.width, (ext.ymax - v[:, 1]) / ext.height])
    kind, mime = IMAGE_FORMATS[image_format]
    img = Image.fromarray(patch.texels(), "RGBA")
    if kind == "JPEG":
        img = img.convert("RGB")
    buf = io.BytesIO()
    img.save(buf, kind, **({"quality": 90} if kind == "JPEG" else {"compress_level": 6}))
    return uvs, buf.getvalue(), mime
