"""Textures: shading and thematic data precomputed as georeferenced RGBA (core paper, 5).

The names below are imported from their modules on first use (PEP 562), so that importing
one texture module (a bake imports the shading and the pyramid) does not import them all
(the OpenGL bake, patches, palettes).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# ``blend`` names both a module and its function: imported now, the function keeps the name
# (a later import of the module would otherwise put the module there).
from approxtree.textures.blend import BLEND_MODES, MultiTexture, blend

#: Public name → the module of approxtree.textures defining it.
_NAMES = {
    "TextureData": "base",
    "GLTopographicShading": "gl_bake",
    "DetailTextures": "detail",
    "ImageTexture": "image",
    "PALETTES": "palettes",
    "Palette": "palettes",
    "get_palette": "palettes",
    "TexturePatch": "patch",
    "PyramidLevel": "pyramid",
    "TexturePyramid": "pyramid",
    "Rebake": "rebake",
    "GouraudShading": "shading",
    "PhongShading": "shading",
    "ShadingTexture": "shading",
    "TopographicShading": "shading",
    "LEGENDS": "thematic",
    "ClassTable": "thematic",
    "ColourRamp": "thematic",
    "ColourReliefFile": "thematic",
    "ThematicTexture": "thematic",
    "rasterize_lines": "thematic",
    "soften": "thematic",
    "WaterLevel": "water",
}

if TYPE_CHECKING:
    from approxtree.textures.base import TextureData
    from approxtree.textures.detail import DetailTextures
    from approxtree.textures.gl_bake import GLTopographicShading
    from approxtree.textures.image import ImageTexture
    from approxtree.textures.palettes import PALETTES, Palette, get_palette
    from approxtree.textures.patch import TexturePatch
    from approxtree.textures.pyramid import PyramidLevel, TexturePyramid
    from approxtree.textures.rebake import Rebake
    from approxtree.textures.shading import (
        GouraudShading,
        PhongShading,
        ShadingTexture,
        TopographicShading,
    )
    from approxtree.textures.thematic import (
        LEGENDS,
        ClassTable,
        ColourRamp,
        ColourReliefFile,
        ThematicTexture,
        rasterize_lines,
        soften,
    )
    from approxtree.textures.water import WaterLevel


def __getattr__(name: str):
    module = _NAMES.get(name)
    if module is None:
        raise AttributeError(f"module 'approxtree.textures' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"approxtree.textures.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_NAMES})


__all__ = [
    "BLEND_MODES",
    "LEGENDS",
    "PALETTES",
    "ClassTable",
    "ColourRamp",
    "ColourReliefFile",
    "DetailTextures",
    "GLTopographicShading",
    "GouraudShading",
    "ImageTexture",
    "MultiTexture",
    "Palette",
    "PhongShading",
    "PyramidLevel",
    "Rebake",
    "ShadingTexture",
    "TextureData",
    "TexturePatch",
    "TexturePyramid",
    "ThematicTexture",
    "TopographicShading",
    "WaterLevel",
    "blend",
    "get_palette",
    "rasterize_lines",
    "soften",
]
