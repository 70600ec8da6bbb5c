"""PayloadProvider: node payloads loaded on background threads into a CPU cache bounded in bytes.

The provider is the first of the renderer's three roles (DESIGN.md, "Renderer roles"): with the
loader of a tile source (render/source.py) it turns a key — a ``MeshKey`` for a patch mesh with
its skirts, a ``TextureKey`` for a texture patch (render/cache_keys.py) — into the arrays the
renderer uploads, reading the tree's store lazily, and keeps them in an LRU cache whose size in
bytes never exceeds its budget (a payload larger than the whole budget is handed to the caller
but not kept).

- ``request(keys, ahead)`` (coarsest first) replaces the wanted list: keys queued by an
  earlier frame and not asked for again are cancelled (a view already left is never loaded
  late); the worker threads take keys from the front of the list. ``ahead`` keys (prefetch:
  predicted views, siblings) come after ``keys`` and are cached only where that evicts no
  payload of ``keys``, so a prefetch never pushes out what the current frame waits for.
- ``is_resident`` / ``get`` answer from the cache without blocking; ``load`` blocks (the root
  of an interactive frame, and every payload of a single offscreen image).
- ``figures()``: hits, misses, loads, bytes, evictions, cancelled, pending.
- ``close()`` stops the threads and empties the cache.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from approxtree.errors import InvalidParameterError

#: Default CPU cache budget (bytes).
DEFAULT_CPU_CACHE_BYTES = 512 << 20


@dataclass(frozen=True)
class Payload:
    """What the renderer uploads for one key.

    vertices: (n, 4) float32 local x, y, z and skirt flag (VERTEX_LAYOUT), triangles: (m, 3)
    uint32 — for a mesh; texels: (h, w, 4) uint8 — for a texture patch. nbytes: the bytes of
    the arrays held (exact).
    """

    vertices: np.ndarray | None = None
    triangles: np.ndarray | None = None
    texels: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.vertices, self.triangles, self.texels) if a is not None)

    @classmethod
    def mesh(
        cls, vertices: np.ndarray, triangles: np.ndarray, flags: np.ndarray, origin: np.ndarray
    ) -> Payload:
        """The payload of a mesh: world vertices (n, 3) relative to ``origin`` (3,) with their
        skirt flags (n,) as VERTEX_LAYOUT float32, triangles (m, 3) as uint32."""
        data = np.empty((len(vertices), 4), dtype=np.float32)
        data[:, :3] = vertices - origin
        data[:, 3] = flags
        return cls(data, np.ascontiguousarray(triangles, dtype=np.uint32).reshape(-1, 3))


class PayloadProvider:
    """Loads payloads with ``loader(key) -> Payload`` on ``threads`` background threads into an
    LRU cache of at most ``cache_bytes`` bytes (see the module docstring)."""

    def __init__(
        self, loader: Callable[[Any], Payload], cache_bytes: int, threads: int = 2
    ) -> None:
        if not (isinstance(cache_bytes, int) and cache_bytes > 0):
            raise InvalidParameterError(f"cpu_cache_bytes must be an int > 0, got {cache_bytes!r}.")
        if not (isinstance(threads, int) and threads > 0):
            raise InvalidParameterError(f"loader threads must be an int > 0, got {threads!r}.")
        self.loader = loader
        self.budget_bytes = int(cache_bytes)
        self.threads = int(threads)
        self._entries: OrderedDict[Hashable, Payload] = OrderedDict()
        self._lock = threading.Lock()
        # Wanted keys not yet started, front first; loads in flight by key.
        self._queue: list[Hashable] = []
        self._queued: set[Hashable] = set()
        # Keys of the latest request proper (prefetched payloads never evict them), and the
        # prefetched keys of its queue.
        self._protected: set[Hashable] = set()
        self._ahead: set[Hashable] = set()
        self._inflight: dict[Hashable, Future] = {}
        self._drains = 0
        self._pool: ThreadPoolExecutor | None = None
        self._closed = False
        # Bumped by ``drop``: a load started before it is not cached (it may be stale).
        self._generation = 0
        self.nbytes = 0
        self.hits = 0
        self.misses = 0
        self.loads = 0
        self.evictions = 0
        self.cancelled = 0
        #: The first error a background load raised (re-raised by the next ``load``).
        self.error: BaseException | None = None

    # -- cache --------------------------------------------------------------------------------

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def keys(self) -> list[Hashable]:
        """Cached keys from least to most recently used."""
        with self._lock:
            return list(self._entries)

    def is_resident(self, keys: Iterable[Hashable]) -> np.ndarray:
        """(k,) bool: whether each key's payload is in the cache."""
        entries = self._entries
        return np.array([k in entries for k in keys], dtype=bool)

    def get(self, key: Hashable) -> Payload | None:
        """The cached payload of ``key`` (now most recently used), or None; never blocks."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                self.misses += 1
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return entry

    def load(self, key: Hashable) -> Payload:
        """The payload of ``key``, loaded in this thread when neither cached nor in flight."""
        self._check_open()
        entry = self.get(key)
        if entry is not None:
            return entry
        with self._lock:
            future = self._inflight.get(key)
            if key in self._queued:
                self._queued.discard(key)
                self._queue.remove(key)
            generation = self._generation
            prefetch = key in self._ahead
        if future is not None:
            payload = future.result()
            if payload is not None and generation == self._generation:
                return payload
            if payload is None:
                self.raise_error()  # the worker's error, once
        payload = self.loader(key)
        self._store(key, payload, generation, prefetch)
        return payload

    # -- background loads ---------------------------------------------------------------------

    def request(self, keys: Iterable[Hashable], ahead: Iterable[Hashable] = ()) -> None:
        """Want ``keys`` (most urgent first: coarsest level first) loaded in the background,
        then ``ahead`` (prefetch, cached only where it evicts none of ``keys``).

        Replaces the previous request: its keys that are neither asked for again nor started
        are cancelled. Cached keys and keys in flight are not queued again.
        """
        self._check_open()
        keys = list(dict.fromkeys(keys))
        protected = set(keys)
        ahead = [k for k in dict.fromkeys(ahead) if k not in protected]
        with self._lock:
            wanted = [
                k for k in [*keys, *ahead] if k not in self._entries and k not in self._inflight
            ]
            keep = set(wanted)
            self._protected = protected
            self._ahead = set(ahead)
            self.cancelled += sum(1 for k in self._queue if k not in keep)
            self._queue = wanted
            self._queued = keep
            start = min(self.threads, len(wanted)) - self._drains
            self._drains += max(0, start)
        if start > 0:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="approxtree-load")
            for _ in range(start):
                self._pool.submit(self._drain)

    @property
    def pending(self) -> int:
        """Keys queued or in flight."""
        return len(self._queue) + len(self._inflight)

    def wait(self) -> None:
        """Block until the current request is loaded (or cancelled); raises the first error
        a load met (once)."""
        while True:
            with self._lock:
                key = self._queue[0] if self._queue else next(iter(self._inflight), None)
            if key is None:
                self.raise_error()
                return
            self.load(key)

    def _drain(self) -> None:
        """One worker: load queued keys, front first, until the queue is empty."""
        while True:
            with self._lock:
                if not self._queue or self._closed:
                    self._drains -= 1
                    return
                key = self._queue.pop(0)
                self._queued.discard(key)
                future: Future = Future()
                self._inflight[key] = future
                generation = self._generation
                prefetch = key in self._ahead
            try:
                payload = self.loader(key)
                self._store(key, payload, generation, prefetch)
                future.set_result(payload)
            except BaseException as exc:  # handed to the next load() of this key
                future.set_result(None)
                with self._lock:
                    # A load started before a drop or rekey read what is now gone: its
                    # error (e.g. a store swapped under it) is no one's to see.
                    if self.error is None and generation == self._generation:
                        self.error = exc
            finally:
                with self._lock:
                    self._inflight.pop(key, None)

    def _store(
        self, key: Hashable, payload: Payload, generation: int, prefetch: bool = False
    ) -> None:
        """Cache ``payload`` (loaded since ``generation``) and evict least recently used
        entries down to the budget; a ``prefetch`` payload only where that evicts no key of
        the current request (else it is dropped)."""
        size = payload.nbytes
        with self._lock:
            self.loads += 1
            stale = generation != self._generation
            if self._closed or stale or size > self.budget_bytes or key in self._entries:
                return
            if prefetch and not self._make_room(size):
                return
            self._entries[key] = payload
            self.nbytes += size
            while self.nbytes > self.budget_bytes:
                _, old = self._entries.popitem(last=False)
                self.nbytes -= old.nbytes
                self.evictions += 1

    def _make_room(self, size: int) -> bool:
        """Evict least recently used entries outside the current request until ``size`` more
        bytes fit (lock held); False, evicting nothing, when they cannot."""
        excess = self.nbytes + size - self.budget_bytes
        if excess <= 0:
            return True
        victims = []
        for k, entry in self._entries.items():
            if k in self._protected:
                continue
            victims.append(k)
            excess -= entry.nbytes
            if excess <= 0:
                break
        if excess > 0:
            return False
        for k in victims:
            self.nbytes -= self._entries.pop(k).nbytes
            self.evictions += 1
        return True

    def raise_error(self) -> None:
        """Raise (once) the first error a background load met, e.g. a StoreError for a
        corrupted chunk, so a frame fails instead of drawing a stand-in forever."""
        with self._lock:
            error, self.error = self.error, None
        if error is not None:
            raise error

    # -- housekeeping -------------------------------------------------------------------------

    def drop(self, predicate: Callable[[Hashable], bool]) -> int:
        """Forget the cached and queued keys that satisfy ``predicate``; returns how many.
        A background load's error not raised yet is forgotten too (it may be stale)."""
        with self._lock:
            self._generation += 1
            self.error = None
            keys = [k for k in self._entries if predicate(k)]
            for k in keys:
                self.nbytes -= self._entries.pop(k).nbytes
            self._queue = [k for k in self._queue if not predicate(k)]
            self._queued = set(self._queue)
        return len(keys)

    def rekey(self, mapping: Callable[[Hashable], Hashable | None]) -> int:
        """Give every cached payload the key ``mapping(key)`` (its node renumbered by a tree
        update), forgetting those mapped to None and every queued key; loads in flight are
        not cached (they may be stale), nor is a background error not raised yet. Returns
        how many payloads were forgotten."""
        with self._lock:
            self._generation += 1
            self.error = None
            kept: OrderedDict[Hashable, Payload] = OrderedDict()
            dropped = 0
            for key, payload in self._entries.items():
                new = mapping(key)
                if new is None:
                    self.nbytes -= payload.nbytes
                    dropped += 1
                else:
                    kept[new] = payload
            self._entries = kept
            self._queue = []
            self._queued = set()
        return dropped

    def figures(self) -> dict[str, Any]:
        """hits, misses, loads, bytes, entries, evictions, cancelled, pending."""
        return {
            "hits": self.hits,
            "misses": self.misses,
            "loads": self.loads,
            "bytes": self.nbytes,
            "entries": len(self._entries),
            "evictions": self.evictions,
            "cancelled": self.cancelled,
            "pending": self.pending,
        }

    def close(self) -> None:
        """Cancel what is queued, wait for the loads in flight, empty the cache."""
        with self._lock:
            self._closed = True
            self.cancelled += len(self._queue)
            self._queue = []
            self._queued = set()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        with self._lock:
            self._entries.clear()
            self.nbytes = 0

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise InvalidParameterError("This provider was closed; create a new one.")
