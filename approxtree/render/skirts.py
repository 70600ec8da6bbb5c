"""Skirts: moved to ``approxtree.patches.skirts`` (the tiles package needs them and may not
import render); this module re-exports them for the renderer and older imports."""

from approxtree.patches.skirts import (
    add_skirts,
    border_edges,
    patches_reach_rect,
    skirt_base,
    skirt_depths,
    skirt_edge_count,
)

__all__ = [
    "add_skirts",
    "border_edges",
    "patches_reach_rect",
    "skirt_base",
    "skirt_depths",
    "skirt_edge_count",
]
