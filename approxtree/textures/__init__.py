"""Textures: shading and thematic data precomputed as georeferenced RGBA (core paper, 5)."""

from approxtree.textures.base import TextureData
from approxtree.textures.blend import BLEND_MODES, MultiTexture, blend
from approxtree.textures.gl_bake import GLTopographicShading
from approxtree.textures.palettes import PALETTES, Palette, get_palette
from approxtree.textures.patch import TexturePatch
from approxtree.textures.pyramid import PyramidLevel, TexturePyramid
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

__all__ = [
    "BLEND_MODES",
    "LEGENDS",
    "PALETTES",
    "ClassTable",
    "ColourRamp",
    "ColourReliefFile",
    "GLTopographicShading",
    "GouraudShading",
    "MultiTexture",
    "Palette",
    "PhongShading",
    "PyramidLevel",
    "ShadingTexture",
    "TextureData",
    "TexturePatch",
    "TexturePyramid",
    "ThematicTexture",
    "TopographicShading",
    "blend",
    "get_palette",
    "rasterize_lines",
    "soften",
]
