"""Frames: what one ``Engine.render`` call drew, its stats, and why a frame shows no terrain.

``FramePlan`` is what a tile source hands the Engine for one frame (the drawn cut, its meshes
grouped by texture patch, the paging figures, the keys to load in the background); ``Frame``
is what the Engine hands back (the image, ``stats`` with the keys of STAT_KEYS, the cut, the
frame state). A frame without terrain is not an error: ``empty_frame_reason`` says why, the
stats carry it ("empty", "warning") and an EmptyFrameWarning is raised.
"""

from __future__ import annotations

import io
import warnings
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from approxtree.errors import ApproxTreeWarning
from approxtree.render.cache_keys import MeshKey, TextureKey
from approxtree.render.frame_state import FrameState
from approxtree.render.selector import Selection

#: Keys of Frame.stats and of ``approxtree render --json``.
STAT_KEYS = (
    "nodes_visited",
    "culled",
    "patches",
    "triangles",
    "max_alpha",
    "max_gamma",
    "select_ms",
    "upload_ms",
    "gpu_uploads",
    "draw_ms",
    "gpu_bytes",
    "texture_patches",
    "texture_switches",
    "stand_ins",
    "texture_stand_ins",
    "pending",
    "paged_uploads",
    "cpu_bytes",
    "empty",
    "warning",
)
#: The paging figures of a frame, in the order of the stats (a settled frame has them all 0):
#: nodes drawn as a resident ancestor meanwhile, nodes still loading, meshes paged onto the GPU
#: ahead of the draw by a frame that does not wait (its budget: ``Paging.max_uploads``), and
#: texture patches drawn as an ancestor's meanwhile. A frame that waits (``render``) pages
#: nothing: its uploads are all in ``gpu_uploads``.
PAGING_KEYS = ("stand_ins", "pending", "paged_uploads", "texture_stand_ins")

#: [(texture patch or None, meshes drawn with it)]: one bind per group.
Groups = list[tuple[TextureKey | None, list[MeshKey]]]


class EmptyFrameWarning(ApproxTreeWarning):
    """A frame shows no terrain (camera under the ground, frustum that misses the terrain)."""


@dataclass
class FramePlan:
    """What a frame draws, as a tile source plans it (``TileSource.plan``).

    selection: the drawn cut (the wanted one, or nearest resident ancestors meanwhile).
    meshes: one key per drawn node, in selection order. groups: the meshes grouped by the
    texture patch they are drawn with ([(None, meshes)] without textures). paging: the
    PAGING_KEYS figures. requests: keys the source's provider loads in the background.
    texture_nodes, texture_gammas: (k,) per drawn node the node whose texture patch it is
    drawn with and that node's γ (None without textures).
    """

    selection: Selection
    meshes: list[MeshKey]
    groups: Groups
    paging: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PAGING_KEYS, 0))
    requests: list[Hashable] = field(default_factory=list)
    texture_nodes: np.ndarray | None = None
    texture_gammas: np.ndarray | None = None


@dataclass
class Frame:
    """One rendered frame.

    image: (h, w, 4) uint8 RGBA, row 0 at the top, alpha 0 where no terrain is drawn (None
    when drawn into a host's framebuffer without read-back). stats: dict of STAT_KEYS.
    positions: (h, w, 4) float64 world x, y, z and a flag (1 surface, 0 skirt, −1 nothing,
    x, y, z NaN there), row 0 at the top, once ``Engine.world_positions(frame)`` read them.
    texture_nodes: (k,) int64, per selected node the node whose texture patch textured it
    (itself or a shared ancestor), and texture_gammas: (k,) that node's γ; None without a
    texture pyramid. meshes: the cache keys of the drawn meshes, in selection order.
    """

    image: np.ndarray | None
    stats: dict[str, Any]
    selection: Selection
    frame_state: FrameState
    positions: np.ndarray | None = None
    texture_nodes: np.ndarray | None = None
    texture_gammas: np.ndarray | None = None
    meshes: list[MeshKey] = field(default_factory=list)

    def _repr_png_(self) -> bytes | None:
        """The image as a PNG, for Jupyter (None when it was not read back)."""
        if self.image is None:
            return None
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(self.image), "RGBA").save(buf, format="PNG")
        return buf.getvalue()


def empty_frame_reason(
    selection: Selection, triangles: int, image: np.ndarray | None
) -> str | None:
    """Why a frame shows no terrain, or None when it shows some.

    image: (h, w, 4) uint8 read back (alpha 0 where nothing is drawn), or None when not read.
    """
    if selection.below_ground:
        return (
            "The camera is below the terrain surface: the frame shows no terrain. Move the "
            "eye above the ground."
        )
    if len(selection.nodes) == 0:
        return (
            "No part of the terrain lies in the view frustum: the frame shows no terrain. "
            "Aim the camera at the terrain."
        )
    if triangles == 0:
        return (
            "The patches in view hold no triangle (isolated valid data points): the frame "
            "shows no terrain."
        )
    if image is not None and not image[..., 3].any():
        return (
            "No terrain pixel was drawn: the terrain's bounding boxes touch the view frustum "
            "but its surface stays outside the image. Aim the camera at the terrain."
        )
    return None


def finish_frame(
    plan: FramePlan,
    fs: FrameState,
    image: np.ndarray | None,
    figures: dict[str, Any],
    opaque: bool,
) -> Frame:
    """The Frame of ``plan`` drawn into ``image`` (or not read back): its stats in STAT_KEYS
    order from the drawn cut and ``figures`` (triangles, timings, cache bytes, texture
    switches), the empty-frame check (an EmptyFrameWarning), and an opaque background made
    opaque in the image (the background pass leaves alpha 0 off the terrain for the check)."""
    sel = plan.selection
    stats = {
        "nodes_visited": sel.stats["nodes_visited"],
        "culled": sel.stats["culled"],
        "patches": len(plan.meshes),
        "triangles": int(figures["triangles"]),
        "max_alpha": sel.stats["max_alpha"],
        "max_gamma": sel.stats["max_gamma"],
        "select_ms": round(figures["select_ms"], 3),
        "upload_ms": round(figures["upload_ms"], 3),
        "gpu_uploads": int(figures["gpu_uploads"]),
        "draw_ms": round(figures["draw_ms"], 3),
        "gpu_bytes": int(figures["gpu_bytes"]),
        "texture_patches": sum(1 for tex, _ in plan.groups if tex is not None),
        "texture_switches": int(figures["texture_switches"]),
        **plan.paging,
        "cpu_bytes": int(figures["cpu_bytes"]),
    }
    reason = empty_frame_reason(sel, stats["triangles"], image)
    if image is not None and opaque:
        image[..., 3] = 255
    stats["empty"] = reason is not None
    stats["warning"] = reason
    if reason is not None:
        # Reported at the caller of Engine.render (this function, render, the caller).
        warnings.warn(reason, EmptyFrameWarning, stacklevel=3)
    return Frame(image, stats, sel, fs, None, plan.texture_nodes, plan.texture_gammas, plan.meshes)
