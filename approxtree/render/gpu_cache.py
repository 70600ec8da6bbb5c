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

import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from approxtree.glsl import VERTEX_LAYOUT
from approxtree.kernels.rgba import box_halve_rgba


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
        release_texture(self.texture)


def release_texture(texture: Any) -> None:
    """Release a moderngl texture, and its GL texture when made by ``_GL.storage`` (moderngl
    deletes none it wraps)."""
    glo = texture.glo
    texture.release()
    if glo in _EXTERNAL:
        _EXTERNAL.discard(glo)
        _gl().delete(glo)


def mip_chain(texels: np.ndarray) -> list[np.ndarray]:
    """The mipmap chain of (h, w, 4) uint8 ``texels``, level 0 first (``texels`` itself), down
    to 1 × 1: each level the 2 × 2 box mean of the one above, rounded half up, of size
    max(1, ⌊w/2⌋) × max(1, ⌊h/2⌋) (an odd last row or column is dropped, as GL sizes it).

    It runs on a worker thread, off the frame: a compiled kernel without the GIL
    (``kernels.rgba.box_halve_rgba``) while both sides exceed 1.
    """
    levels = [texels]
    a = texels
    while a.shape[0] > 1 and a.shape[1] > 1:
        h, w = a.shape[:2]
        half = np.empty((h // 2, w // 2, a.shape[2]), dtype=np.uint8)
        box_halve_rgba(np.ascontiguousarray(a), half)
        a = half
        levels.append(a)
    while a.shape[0] > 1 or a.shape[1] > 1:
        h, w = a.shape[:2]
        # A side of 1 stays 1: its texels pair with themselves.
        r = a[: 2 * (h // 2)] if h > 1 else np.concatenate([a, a])
        r = r[:, : 2 * (w // 2)] if w > 1 else np.concatenate([r, r], axis=1)
        total = r[0::2, 0::2].astype(np.uint16)
        total += r[1::2, 0::2]
        total += r[0::2, 1::2]
        total += r[1::2, 1::2]
        total += 2
        a = (total >> 2).astype(np.uint8)
        levels.append(a)
    return levels


@dataclass
class TextureUpload:
    """A texture patch written over several frames: ``texture`` with every mip level
    allocated, ``levels`` its texels (level 0 first, (h, w, 4) uint8 each), and the next
    ``level`` and ``row`` to write. Drawn only once complete (``GpuCache.upload_staged``)."""

    texture: Any
    levels: list[np.ndarray]
    level: int = 0
    row: int = 0

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.levels)

    def write(self, max_bytes: int) -> bool:
        """Write the next rows of at most ``max_bytes`` (one row at least); True when the
        last level's last row is written."""
        a = self.levels[self.level]
        h = a.shape[0]
        rows = max(1, min(h - self.row, max_bytes // max(a[0].nbytes, 1)))
        band = np.ascontiguousarray(a[self.row : self.row + rows])
        _gl().sub_image(self.texture.glo, self.level, self.row, band)
        self.row += rows
        if self.row >= h:
            self.level, self.row = self.level + 1, 0
        return self.level >= len(self.levels)

    def release(self) -> None:
        release_texture(self.texture)


class _GL:
    """The few GL calls moderngl lacks (a texture's storage with every mip level, writing a
    level other than 0), called through ctypes on the current context (libglvnd's
    libOpenGL dispatches to it)."""

    TEXTURE_2D, RGBA8, RGBA, UNSIGNED_BYTE, TEXTURE0 = 0x0DE1, 0x8058, 0x1908, 0x1401, 0x84C0

    def __init__(self) -> None:
        import ctypes

        lib = None
        for name in ("libOpenGL.so.0", "libGL.so.1"):
            try:
                lib = ctypes.CDLL(name)
                break
            except OSError:
                continue
        if lib is None or not hasattr(lib, "glTexStorage2D"):
            raise OSError("no libOpenGL or libGL with glTexStorage2D")
        u, i, p = ctypes.c_uint, ctypes.c_int, ctypes.c_void_p
        lib.glGenTextures.argtypes = [i, p]
        lib.glDeleteTextures.argtypes = [i, p]
        lib.glTexStorage2D.argtypes = [u, i, u, i, i]
        lib.glTexSubImage2D.argtypes = [u, i, i, i, i, i, u, u, p]
        lib.glBindTexture.argtypes = [u, u]
        lib.glActiveTexture.argtypes = [u]
        self.ctypes, self.lib = ctypes, lib

    def _bind(self, glo: int) -> None:
        # Unit 0: every draw binds its own textures again (the renderer's per frame).
        self.lib.glActiveTexture(self.TEXTURE0)
        self.lib.glBindTexture(self.TEXTURE_2D, glo)

    def storage(self, w: int, h: int, levels: int) -> int:
        """A new RGBA8 texture of w × h with ``levels`` mip levels, allocated at once (one
        allocation: levels defined one by one would be copied into one at the first draw)."""
        ids = (self.ctypes.c_uint * 1)()
        self.lib.glGenTextures(1, ids)
        self._bind(ids[0])
        self.lib.glTexStorage2D(self.TEXTURE_2D, levels, self.RGBA8, w, h)
        return int(ids[0])

    def sub_image(self, glo: int, level: int, row: int, band: np.ndarray) -> None:
        """Write (rows, w, 4) uint8 ``band`` at ``row`` of ``level`` of texture ``glo``."""
        self._bind(glo)
        rows, w = band.shape[:2]
        self.lib.glTexSubImage2D(
            self.TEXTURE_2D, level, 0, row, w, rows, self.RGBA, self.UNSIGNED_BYTE,
            band.ctypes.data,
        )  # fmt: skip

    def delete(self, glo: int) -> None:
        self.lib.glDeleteTextures(1, (self.ctypes.c_uint * 1)(glo))


_GL_CALLS: list[_GL] = []
#: GL names of the textures made by ``_GL.storage`` (moderngl wraps them, GL deletes them).
_EXTERNAL: set[int] = set()


def _gl() -> _GL:
    """The process's _GL (loaded on first use)."""
    if not _GL_CALLS:
        _GL_CALLS.append(_GL())
    return _GL_CALLS[0]


def staged_uploads_available() -> bool:
    """Whether textures can be written over frames here (the GL library loads)."""
    try:
        _gl()
    except OSError:
        return False
    return True


#: Bytes of texels written in one step of a staged texture upload (about 2 ms on llvmpipe).
UPLOAD_STEP_BYTES = 4 << 20


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
        # Texture patches being written over frames (not drawable until complete), oldest first.
        self._staged: OrderedDict[Hashable, TextureUpload] = OrderedDict()
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
        texture coordinate v = 0, uploaded now with mipmaps and trilinear filtering (the mip
        chain of ``mip_chain``, as the textures written over frames get)."""
        import moderngl

        entry = self._entries.get(key)
        if entry is not None:
            self._entries.move_to_end(key)
            return entry  # type: ignore[return-value]
        texels = np.ascontiguousarray(build(), dtype=np.uint8)
        h, w = texels.shape[:2]
        if staged_uploads_available():
            # The same mipmaps whether a patch was written at once or over frames.
            self.unstage(lambda k: k == key)
            self.stage_texture(key, mip_chain(texels))
            upload = self._staged.pop(key)
            while not upload.write(upload.nbytes):
                pass
            return self._add(key, GpuTexture(upload.texture, mipmap_bytes(w, h)))
        tex = self.ctx.texture((w, h), 4, texels, dtype="f1")
        tex.repeat_x = False
        tex.repeat_y = False
        # Hardware mipmaps per texture patch (core paper, 3.3), sampled trilinearly (where
        # GL's library cannot be called: the driver's filter, within a few levels of ours).
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        return self._add(key, GpuTexture(tex, mipmap_bytes(w, h)))

    # -- texture patches written over frames ---------------------------------------------------

    def is_staged(self, key: Hashable) -> bool:
        """Whether ``key``'s texture is being written over frames (not drawable yet)."""
        return key in self._staged

    def staged(self) -> list[Hashable]:
        """Keys of the textures being written, oldest first."""
        return list(self._staged)

    def stage_texture(self, key: Hashable, levels: list[np.ndarray]) -> None:
        """Allocate ``key``'s texture with the mip chain ``levels`` ((h, w, 4) uint8, level 0
        first, ``mip_chain``), to be written by ``upload_staged`` over the next frames."""
        import moderngl

        h, w = levels[0].shape[:2]
        # moderngl neither allocates nor writes mip levels itself: GL makes the texture,
        # moderngl wraps it (external: released by release_texture).
        tex = self.ctx.external_texture(_gl().storage(w, h, len(levels)), (w, h), 4, 0, "f1")
        _EXTERNAL.add(tex.glo)
        tex.repeat_x = False
        tex.repeat_y = False
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._staged[key] = TextureUpload(tex, levels)

    def upload_staged(
        self,
        budget_ms: float,
        step_bytes: int = UPLOAD_STEP_BYTES,
        order: Sequence[Hashable] | None = None,
    ) -> int:
        """Write staged textures in ``order`` (staged keys; None: oldest first) for about
        ``budget_ms`` (one step of ``step_bytes`` at least); a complete one becomes an entry
        (drawable). Returns how many were completed."""
        t0 = time.perf_counter()
        completed = 0
        for key in list(self._staged) if order is None else order:
            upload = self._staged[key]
            while True:
                done = upload.write(step_bytes)
                if done:
                    del self._staged[key]
                    h, w = upload.levels[0].shape[:2]
                    self._add(key, GpuTexture(upload.texture, mipmap_bytes(w, h)))
                    completed += 1
                if (time.perf_counter() - t0) * 1e3 >= budget_ms:
                    return completed
                if done:
                    break
        return completed

    def unstage(self, predicate: Callable[[Hashable], bool]) -> int:
        """Release the staged textures whose key satisfies ``predicate``; returns how many."""
        keys = [k for k in self._staged if predicate(k)]
        for k in keys:
            self._staged.pop(k).release()
        return len(keys)

    def drop(self, predicate: Callable[[Hashable], bool]) -> int:
        """Release the entries whose key satisfies ``predicate``; returns how many."""
        self.unstage(predicate)
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
        # Half-written textures are simply written again under their new keys.
        self.unstage(lambda key: True)
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
        self.unstage(lambda key: True)
        for entry in self._entries.values():
            entry.release()
        self._entries.clear()
        self.pinned.clear()
        self.nbytes = 0
