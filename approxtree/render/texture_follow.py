"""Which cached texture patches a re-baked pyramid changed: those meeting a changed tile.

A re-bake (``textures.rebake``) rewrites whole tiles of every level and gives the pyramid a new
build id; every tile of a pyramid carries the CRC-32C of its decoded texels
(``TexturePyramid.tile_crc32c``, public). So the tiles whose texels changed are found from the
two pyramids' checksums alone, whatever the files look like on disk: per level, the tiles whose
checksum differs. A texture patch (``TextureKey``: a window of one level) is stale when its
window meets a changed tile of its own level; every other patch holds the very texels the new
pyramid would give it and stays in the caches.

Pyramids that cannot be compared (other level sizes, transforms or bands, a detail pyramid
added or removed) change every patch.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import Any

from approxtree.render.cache_keys import TextureKey

#: The tiles of each level whose texels changed: (tile row, tile column).
ChangedTiles = list[set[tuple[int, int]]]


def tile_side(pyramid: Any) -> int:
    """The side (texels) of the pyramid's square tiles, from its checksum grid.

    With n ≥ 2 tiles of a power-of-two side T along a level's side of s texels,
    (n − 1)·T < s ≤ n·T, so ceil(s / n) lies in (T/2, T] and its next power of two is T. A
    pyramid whose levels are all one tile across says nothing of T, and needs nothing: its
    one tile per level is the whole level (the level's largest side stands in).
    """
    side = 1
    for lv, rows in zip(pyramid.levels, pyramid.tile_crc32c, strict=True):
        for size, n in ((lv.height, len(rows)), (lv.width, len(rows[0]))):
            if n >= 2:
                return 1 << (-(-size // n) - 1).bit_length()
            side = max(side, size)
    return side


def changed_tiles(old: Any, new: Any) -> ChangedTiles | None:
    """Per level of two TexturePyramids of one lattice, the tiles whose checksums differ;
    None when the pyramids are not comparable (module doc)."""
    same_shape = (
        len(old.levels) == len(new.levels)
        and old.bands == new.bands
        and all(
            (a.width, a.height) == (b.width, b.height) and a.transform == b.transform
            for a, b in zip(old.levels, new.levels, strict=True)
        )
    )
    if not same_shape:
        return None
    out: ChangedTiles = []
    for a, b in zip(old.tile_crc32c, new.tile_crc32c, strict=True):
        out.append(
            {
                (r, c)
                for r, (row_a, row_b) in enumerate(zip(a, b, strict=True))
                for c, (x, y) in enumerate(zip(row_a, row_b, strict=True))
                if x != y
            }
        )
    return out


def stale_textures(
    old: Sequence[Any] | None, new: Sequence[Any] | None
) -> Callable[[Hashable], bool]:
    """The predicate of the cache keys a change of pyramids makes stale.

    old, new: the pyramids of each ``TextureKey.source`` (0: base, 1: detail) before and
    after, or None (no textures). True for a TextureKey meeting a changed tile of its level
    (module doc); False for every other key (meshes stay).
    """
    if not old or not new or len(old) != len(new):

        def every(key: Hashable) -> bool:
            return isinstance(key, TextureKey)

        return every
    # Per source: its tile side and changed tiles (None: all of that source's patches).
    changes = []
    for a, b in zip(old, new, strict=True):
        changes.append((tile_side(b), changed_tiles(a, b)))

    def stale(key: Hashable) -> bool:
        if not isinstance(key, TextureKey):
            return False
        side, tiles = changes[key.source]
        if tiles is None:
            return True
        level = tiles[key.level]
        if not level:
            return False
        r0, r1 = key.row0 // side, (key.row0 + key.height - 1) // side
        c0, c1 = key.col0 // side, (key.col0 + key.width - 1) // side
        return any(r0 <= r <= r1 and c0 <= c <= c1 for r, c in level)

    return stale


def pyramids_of(binding: Any) -> list[Any] | None:
    """The pyramids of each texture source of a TextureBinding (None: no textures)."""
    return None if binding is None else list(binding.pyramids)


__all__ = ["ChangedTiles", "changed_tiles", "pyramids_of", "stale_textures", "tile_side"]
