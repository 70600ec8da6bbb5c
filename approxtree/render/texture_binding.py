"""Texture binding: which texture patch each drawn mesh is drawn with, and how it is sampled.

With a texture pyramid every mesh is drawn with the texture patch Q_N of a node (its own, or a
shared ancestor's, render/texture_sharing.py) or of a full-resolution chunk: the finest window
of the pyramid covering that rectangle within the maximum texture size (core paper, 3.3). The
``TextureBinding`` of one pyramid

- remembers the patch of each owner (at most TEXTURE_PATCH_MEMO of them, however many nodes a
  fly-over visits) and keys it by its window (``TextureKey``: owners with the same window share
  one GPU texture);
- groups a frame's meshes by texture patch (``groups``), so each patch is bound once, and, in
  an interactive frame, draws a patch not loaded yet with the root's (``page``);
- gives the uv transform of a patch (local x, y → texture coordinates) and its texels.

With a ``DetailTextures`` (a base pyramid refined by a detail pyramid, textures/detail.py) an
owner at or below the detail level and inside the detail's footprint takes its patch from the
detail pyramid (its key's ``source`` 1), every other owner from the base.

``as_pyramid`` checks what a caller passes as textures: a TexturePyramid or its folder, in the
terrain's CRS and overlapping its domain (a DetailTextures: both of its pyramids).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError
from approxtree.geometry.rect import Rect
from approxtree.render.cache_keys import NODE, MeshKey, TextureKey
from approxtree.render.frame import Groups
from approxtree.textures.detail import DetailTextures
from approxtree.textures.patch import TexturePatch
from approxtree.textures.pyramid import TexturePyramid

#: Texture windows of owners remembered at most (each a few hundred bytes).
TEXTURE_PATCH_MEMO = 1 << 16
#: The owner whose texture patch stands in for one not loaded yet: the root's.
ROOT = MeshKey(NODE, 0)


class TextureBinding:
    """The texture patches of one pyramid for one tree (see the module docstring).

    pyramid: a TexturePyramid, or a DetailTextures with ``level_of(owner)`` -> the owner's tree
    level; origin: (3,) the tree's local origin (uv works on local coordinates);
    rect_of(owner) -> Rect: the rectangle an owner's patch covers (a node's domain, a chunk's
    box).
    """

    def __init__(
        self,
        pyramid: TexturePyramid | DetailTextures,
        origin: np.ndarray,
        rect_of: Callable[[MeshKey], Rect],
        level_of: Callable[[MeshKey], int] | None = None,
    ) -> None:
        self.detail = pyramid if isinstance(pyramid, DetailTextures) else None
        #: The base pyramid, and the pyramid of each key source (0: base, 1: detail).
        self.pyramid = pyramid.base if isinstance(pyramid, DetailTextures) else pyramid
        self.pyramids = [self.pyramid] + ([self.detail.detail] if self.detail else [])
        self.origin = origin
        self.rect_of = rect_of
        self.level_of = level_of
        #: The pyramid holds grey shading: the renderer shades the palette with it.
        self.shading = is_shading(self.pyramid)
        self._patches: dict[MeshKey, tuple[TexturePatch, int]] = {}

    def source_of(self, owner: MeshKey) -> int:
        """0 when ``owner`` takes its patch from the base pyramid, 1 from the detail one."""
        if self.detail is None or self.level_of is None:
            return 0
        rect = np.array([self.rect_of(owner).as_tuple()])
        return int(self.detail.uses_detail(np.array([self.level_of(owner)]), rect)[0])

    def patch(self, owner: MeshKey) -> TexturePatch:
        """The TexturePatch of ``owner`` (made on first use; references the pyramid's data)."""
        return self._patch(owner)[0]

    def _patch(self, owner: MeshKey) -> tuple[TexturePatch, int]:
        """The TexturePatch of ``owner`` and the source of its pyramid."""
        held = self._patches.get(owner)
        if held is None:
            # Bounded like the caches, however many nodes a fly-over visits.
            if len(self._patches) >= TEXTURE_PATCH_MEMO:
                self._patches.clear()
            source = self.source_of(owner)
            patch = TexturePatch.for_rect(self.pyramids[source], self.rect_of(owner))
            held = self._patches[owner] = (patch, source)
        return held

    def key(self, owner: MeshKey) -> TextureKey:
        """The TextureKey of ``owner``'s patch."""
        patch, source = self._patch(owner)
        return TextureKey.of(patch, source)

    def forget(self) -> None:
        """Forget the owners' patches (their nodes were renumbered by a tree update)."""
        self._patches.clear()

    def groups(self, meshes: list[MeshKey], owners: list[MeshKey]) -> Groups:
        """[(texture key, meshes)]: ``meshes`` grouped by the texture patch of their
        ``owners`` (one owner per mesh), in first-seen order."""
        return group_meshes(meshes, [self.key(owner) for owner in owners])

    def page(self, groups: Groups, loaded: Callable[[TextureKey], bool]) -> tuple[Groups, list]:
        """The groups of an interactive frame, drawable without waiting for the store: a
        texture patch not ``loaded`` (neither on the GPU nor in the CPU cache) is replaced by
        the root's (coarser, always drawable: its one blocking read) and requested.

        Returns (groups, texture keys to request).
        """
        return page_groups(groups, loaded, self.key(ROOT))

    def uv(self, key: TextureKey) -> tuple[float, float, float, float]:
        """uv = local.xy * t[:2] + t[2:] of a texture window (u along columns, v along rows,
        texel row 0 at v = 0)."""
        level, c0, r0, w, h, source = key
        t = self.pyramids[source].levels[level].transform
        ox, oy, _ = self.origin
        # col = (x − c) / a and row = (y − f) / e for a north-up level, x = local x + ox.
        return (
            1.0 / (t.a * w),
            1.0 / (t.e * h),
            (ox - t.c) / (t.a * w) - c0 / w,
            (oy - t.f) / (t.e * h) - r0 / h,
        )

    def texels(self, key: TextureKey) -> np.ndarray:
        """(h, w, 4) uint8 texels of a texture window (read from the pyramid's tiles)."""
        level, c0, r0, w, h, source = key
        texels = TexturePatch(self.pyramids[source], level, c0, r0, w, h).texels()
        return np.ascontiguousarray(texels, dtype=np.uint8)


def group_meshes(meshes: list[MeshKey], patches: list[Hashable | None]) -> Groups:
    """[(patch key, meshes)]: ``meshes`` grouped by their texture (or normal) patch keys
    ``patches`` (one per mesh; None: no patch of its own), in first-seen order."""
    # Any keys: texture patches (TextureKey) or normal patches (render/normal_map.NormalKey).
    groups: dict[Any, list[MeshKey]] = {}
    for key, patch in zip(meshes, patches, strict=True):
        groups.setdefault(patch, []).append(key)
    return list(groups.items())


def page_groups(
    groups: Groups, loaded: Callable[[Any], bool], stand_in: Hashable | None
) -> tuple[Groups, list]:
    """``groups`` drawable without waiting for the store: a patch not ``loaded`` is replaced
    by ``stand_in`` (always drawable) and requested; a None patch stays. Returns (groups,
    patch keys to request)."""
    merged: dict[Any, list[MeshKey]] = {}
    requests: list[Hashable] = []
    for tex_key, keys in groups:
        drawn: Any = tex_key
        if tex_key is not None and not loaded(tex_key):
            requests.append(tex_key)
            drawn = stand_in
        merged.setdefault(drawn, []).extend(keys)
    return list(merged.items()), requests


def as_pyramid(textures: Any, terrain: Any) -> TexturePyramid | DetailTextures | None:
    """``textures`` as a TexturePyramid matching ``terrain`` (opened from a folder), a
    DetailTextures whose pyramids both match it, or None."""
    if isinstance(textures, DetailTextures):
        check_pyramid_matches(textures.base, terrain)
        check_pyramid_matches(textures.detail, terrain)
        return textures
    if textures is None or isinstance(textures, TexturePyramid):
        pyramid = textures
    elif isinstance(textures, str | os.PathLike):
        pyramid = TexturePyramid(textures)
    else:
        raise InvalidParameterError(
            "textures must be a TexturePyramid, the folder of one, a DetailTextures or None; "
            "got a "
            f"{type(textures).__name__}."
        )
    if pyramid is not None:
        check_pyramid_matches(pyramid, terrain)
    return pyramid


def check_pyramid_matches(pyramid: TexturePyramid, terrain: Any) -> None:
    """A pyramid must share the terrain's CRS and overlap its domain."""
    if pyramid.crs and terrain.crs:
        from rasterio.crs import CRS

        try:
            same = CRS.from_user_input(pyramid.crs) == CRS.from_user_input(terrain.crs)
        except Exception:
            same = True
        if not same:
            raise InvalidParameterError(
                f"The texture pyramid in {pyramid.folder} is in {pyramid.crs}, the terrain in "
                f"{terrain.crs}; bake the textures from this terrain (approxtree bake)."
            )
    lv = pyramid.levels[0]
    x0, y0 = lv.transform @ (0, 0)
    x1, y1 = lv.transform @ (lv.width, lv.height)
    d = terrain.domain
    if min(x0, x1) > d.xmax or max(x0, x1) < d.xmin or min(y0, y1) > d.ymax or max(y0, y1) < d.ymin:
        raise InvalidParameterError(
            f"The texture pyramid in {pyramid.folder} does not overlap the terrain's domain; "
            "bake the textures from this terrain (approxtree bake)."
        )


def is_shading(pyramid: TexturePyramid) -> bool:
    """True when a pyramid holds grey shading (R = G = B on every texel of its coarsest
    level, e.g. a baked hillshade): the renderer then shades the palette with it."""
    texels = np.asarray(pyramid.level(len(pyramid) - 1))
    if texels.ndim != 3 or texels.shape[-1] < 3:
        return False
    rgb = texels[..., :3]
    return bool((rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all())
