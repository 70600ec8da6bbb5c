"""Textures: shading and thematic data precomputed as georeferenced RGBA (core paper, 5)."""

from approxtree.textures.base import TextureData
from approxtree.textures.blend import BLEND_MODES, MultiTexture, blend
from approxtree.textures.shading import ShadingTexture, TopographicShading
from approxtree.textures.thematic import (
    ClassTable,
    ColourRamp,
    ColourReliefFile,
    ThematicTexture,
    rasterize_lines,
)

__all__ = [
    "BLEND_MODES",
    "ClassTable",
    "ColourRamp",
    "ColourReliefFile",
    "MultiTexture",
    "ShadingTexture",
    "TextureData",
    "ThematicTexture",
    "TopographicShading",
    "blend",
    "rasterize_lines",
]
