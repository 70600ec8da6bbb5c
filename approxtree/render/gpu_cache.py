"""GpuCache: patch meshes and texture patches on the GPU, bounded in bytes, least recently used out.

A mesh entry owns a vertex buffer, an index buffer and one vertex array per program it was
drawn with; a texture entry owns one RGBA8 texture with its hardware mipmaps. ``get`` and
``get_texture`` return the entry of a key, building and uploading it on a miss; when the total
exceeds the budget, the least recently used entries are released — except the one just
requested and the ``pinned`` keys (the texture bound while its meshes are drawn), so a single
patch larger than the budget can still be drawn. Nothing relies on the garbage collector:
``release()`` frees every buffer now.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from approxtree.glsl import VERTEX_LAYOUT


@dataclass
class GpuMesh:
    """One uploaded mesh. nbytes: vertex + index buffer bytes; triangles: index count / 3.

    A mesh of no triangles has no buffers (vbo and ibo None) and is never drawn.
    """

    vbo: Any
    ibo: Any
    nbytes: int
    triangles: int
    vaos: dict[int, Any] = field(default_factory=dict)

    def vao(self, ctx: Any, program: Any) -> Any:
        """The vertex array binding this mesh to ``program`` (made on first use)."""
        key = program.glo
        if key not in self.vaos:
            # skip_errors: a program may leave an attribute of the layout unused.
            self.vaos[key] = ctx.vertex_array(
                program,
                [(self.vbo, *VERTEX_LAYOUT)],
                self.ibo,
                index_element_size=4,
                skip_errors=True,
            )
        return self.vaos[key]

    def release(self) -> None:
        for vao in self.vaos.values():
            vao.release()
        self.vaos.clear()
        if self.vbo is not None:
            self.vbo.release()
            self.ibo.release()


def mipmap_bytes(width: int, height: int, components: int = 4) -> int:
    """Bytes of a texture of width × height texels with its full mipmap chain."""
    total = 0
    w, h = width, height
    while True:
        total += w * h * components
        if w == 1 and h == 1:
            return total
        w, h = max(1, w // 2), max(1, h // 2)


@dataclass
class GpuTexture:
    """One uploaded texture patch: RGBA8 with mipmaps, trilinear. nbytes: all mip levels."""

    texture: Any
    nbytes: int

    def release(self) -> None:
        self.texture.release()


class GpuCache:
    """LRU cache of GpuMesh entries on ``ctx``, at most ``budget_bytes`` (soft, see above).

    Figures: ``nbytes`` in use, ``uploads`` and ``evictions`` since creation.
    """

    def __init__(self, ctx: Any, budget_bytes: int) -> None:
        if budget_bytes <= 0:
            raise ValueError(f"budget_bytes must be > 0, got {budget_bytes}")
        self.ctx = ctx
        self.budget_bytes = int(budget_bytes)
        self._entries: OrderedDict[Hashable, GpuMesh | GpuTexture] = OrderedDict()
        #: Keys never evicted (set by the caller around a draw).
        self.pinned: set[Hashable] = set()
        self.nbytes = 0
        self.uploads = 0
        self.evictions = 0

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def keys(self) -> list[Hashable]:
        """Keys from least to most recently used."""
        return list(self._entries)

    def is_resident(self, keys: Sequence[Hashable]) -> np.ndarray:
        """(k,) bool: whether each of ``keys`` has an entry (no entry is touched)."""
        return np.array(list(map(self._entries.__contains__, keys)), dtype=bool)

    def get(self, key: Hashable, build: Callable[[], tuple[np.ndarray, np.ndarray]]) -> GpuMesh:
        """The mesh of ``key``; on a miss ``build()`` gives (vertex data (n, 4) float32 in
        VERTEX_LAYOUT, triangles (m, 3) uint32) to upload."""
        entry = self._entries.get(key)
        if entry is not None:
            self._entries.move_to_end(key)
            return entry  # type: ignore[return-value]
        vertex_data, triangles = build()
        # A patch without triangles (isolated valid points) draws nothing, and GL refuses
        # empty buffers: its entry holds none (triangles 0; callers skip it).
        if len(triangles) == 0:
            return self._add(key, GpuMesh(None, None, 0, 0))
        vbo = self.ctx.buffer(np.ascontiguousarray(vertex_data, dtype="f4").tobytes())
        ibo = self.ctx.buffer(np.ascontiguousarray(triangles, dtype="u4").tobytes())
        return self._add(key, GpuMesh(vbo, ibo, vbo.size + ibo.size, len(triangles)))

    def get_texture(self, key: Hashable, build: Callable[[], np.ndarray]) -> GpuTexture:
        """The texture of ``key``; on a miss ``build()`` gives (h, w, 4) uint8 texels, row 0 at
        texture coordinate v = 0, uploaded with mipmaps and trilinear filtering."""
        import moderngl

        entry = self._entries.get(key)
        if entry is not None:
            self._entries.move_to_end(key)
            return entry  # type: ignore[return-value]
        texels = np.ascontiguousarray(build(), dtype=np.uint8)
        h, w = texels.shape[:2]
        tex = self.ctx.texture((w, h), 4, texels.tobytes(), dtype="f1")
        tex.repeat_x = False
        tex.repeat_y = False
        # Hardware mipmaps per texture patch (core paper, 3.3), sampled trilinearly.
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        return self._add(key, GpuTexture(tex, mipmap_bytes(w, h)))

    def drop(self, predicate: Callable[[Hashable], bool]) -> int:
        """Release the entries whose key satisfies ``predicate``; returns how many."""
        keys = [k for k in self._entries if predicate(k)]
        for k in keys:
            entry = self._entries.pop(k)
            self.nbytes -= entry.nbytes
            entry.release()
        return len(keys)

    def rekey(self, mapping: Callable[[Hashable], Hashable | None]) -> int:
        """Give every entry the key ``mapping(key)`` (its node renumbered by a tree update),
        keeping the LRU order; entries mapped to None are released. Returns how many."""
        kept: OrderedDict[Hashable, GpuMesh | GpuTexture] = OrderedDict()
        dropped = 0
        for key, entry in self._entries.items():
            new = mapping(key)
            if new is None:
                self.nbytes -= entry.nbytes
                entry.release()
                dropped += 1
            else:
                kept[new] = entry
        self._entries = kept
        self.pinned = {k for k in (mapping(p) for p in self.pinned) if k is not None}
        return dropped

    def _add(self, key: Hashable, entry):
        self._entries[key] = entry
        self.nbytes += entry.nbytes
        self.uploads += 1
        self._evict(keep=key)
        return entry

    def _evict(self, keep: Hashable) -> None:
        """Release least recently used entries until the budget holds (``keep`` and the
        pinned keys stay)."""
        # Within budget (the usual case) nothing is listed: a frame of n new meshes costs
        # O(n), not O(n²) (listing every entry on every upload took 0.5 s for 3,236 meshes).
        if self.nbytes <= self.budget_bytes:
            return
        for old_key in list(self._entries):
            if self.nbytes <= self.budget_bytes:
                break
            if old_key == keep or old_key in self.pinned:
                continue
            old = self._entries.pop(old_key)
            self.nbytes -= old.nbytes
            old.release()
            self.evictions += 1

    def release(self) -> None:
        """Free every buffer and vertex array now; the cache stays usable (empty)."""
        for entry in self._entries.values():
            entry.release()
        self._entries.clear()
        self.pinned.clear()
        self.nbytes = 0
