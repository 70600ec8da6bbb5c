"""The server's tile cache: made responses by key, least recently used first, bounded in bytes.

An ``Entry`` is one made resource: its media type, its bytes as made (``body``: gzip for
quantized-mesh, which is stored gzip-compressed) and, for compressible types, the other
encoding (``gzip`` made beside the identity bytes; the identity of a gzip-made body is inflated
on demand, for the rare client that does not take gzip), and a strong ETag (BLAKE2b of the
body; the other representation's tag carries a suffix). Its size is every byte it holds plus
``ENTRY_OVERHEAD``.

``TileCache.get_or_make(key, make)`` returns the cached entry, or runs ``make`` (a blocking
function) on the server's worker threads, once per key however many requests wait for it
(single flight): a request that goes away (a client disconnecting) stops waiting, the tile is
still made and kept for the next one. At most ``max_pending`` tiles are made or queued at
once; past that a request gets ``Busy`` (HTTP 503) at once instead of queueing without bound.
Thread-safe: worker threads put entries too (the tiles a tileset.json walk makes).
"""

from __future__ import annotations

import asyncio
import gzip
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import Executor
from dataclasses import dataclass, field

from approxtree.errors import ApproxTreeError

#: Bytes an entry costs beyond its bodies (key, object, headers), counted against the bound.
ENTRY_OVERHEAD = 512
#: Media types worth gzip on the wire (images are compressed already).
COMPRESSIBLE = ("application/json", "model/gltf-binary", "application/vnd.quantized-mesh")


class Busy(ApproxTreeError):
    """Too many tiles are being made: the request is refused (HTTP 503), not queued."""


@dataclass
class Entry:
    """One made resource (module docstring). ``gzipped``: whether ``body`` is gzip-encoded."""

    media_type: str
    body: bytes
    gzipped: bool = False
    gzip: bytes | None = None
    etag: str = field(init=False)

    def __post_init__(self) -> None:
        self.etag = '"' + hashlib.blake2b(self.body, digest_size=16).hexdigest() + '"'

    @classmethod
    def made(cls, media_type: str, body: bytes, gzipped: bool = False) -> Entry:
        """An entry of freshly made bytes; the gzip representation of a compressible
        identity body is made now (on the worker thread that made the body)."""
        entry = cls(media_type, body, gzipped)
        if not gzipped and media_type in COMPRESSIBLE:
            entry.gzip = gzip.compress(body, compresslevel=6, mtime=0)
        return entry

    @property
    def nbytes(self) -> int:
        return len(self.body) + len(self.gzip or b"") + ENTRY_OVERHEAD

    def representation(self, gzip_ok: bool) -> tuple[bytes, str | None, str]:
        """(bytes, Content-Encoding or None, ETag) sent to a client that does (``gzip_ok``)
        or does not take gzip."""
        if self.gzipped:
            if gzip_ok:
                return self.body, "gzip", self.etag
            return gzip.decompress(self.body), None, self.etag[:-1] + '-identity"'
        if gzip_ok and self.gzip is not None:
            return self.gzip, "gzip", self.etag[:-1] + '-gzip"'
        return self.body, None, self.etag

    def matches(self, if_none_match: str) -> bool:
        """Whether an If-None-Match header names this entity (any representation of it, weak
        comparison as RFC 9110 has it for GET), or is ``*``."""
        if if_none_match.strip() == "*":
            return True
        base = self.etag[1:-1]
        for tag in if_none_match.split(","):
            tag = tag.strip().removeprefix("W/").strip('"')
            if tag in (base, base + "-gzip", base + "-identity"):
                return True
        return False


class TileCache:
    """Entries by key, bounded by ``limit`` bytes (module docstring); ``executor`` runs the
    makers."""

    def __init__(self, limit: int, executor: Executor, max_pending: int = 256) -> None:
        self.limit = int(limit)
        self.executor = executor
        self.max_pending = int(max_pending)
        self._entries: OrderedDict[Hashable, Entry] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self._pending: dict[Hashable, asyncio.Future] = {}
        self.hits = 0
        self.misses = 0

    def get(self, key: Hashable) -> Entry | None:
        with self._lock:
            entry = self._entries.get(key)
            if entry is not None:
                self._entries.move_to_end(key)
                self.hits += 1
            return entry

    def put(self, key: Hashable, entry: Entry) -> None:
        """Keep ``entry`` (an entry larger than the whole bound is not kept), evicting the
        least recently used ones beyond the bound."""
        size = entry.nbytes
        if size > self.limit:
            return
        with self._lock:
            old = self._entries.pop(key, None)
            if old is not None:
                self._bytes -= old.nbytes
            self._entries[key] = entry
            self._bytes += size
            while self._bytes > self.limit:
                _, dropped = self._entries.popitem(last=False)
                self._bytes -= dropped.nbytes

    async def get_or_make(self, key: Hashable, make: Callable[[], Entry]) -> Entry:
        """The entry of ``key``, made by ``make()`` on a worker thread when it is not held;
        Busy when max_pending tiles are being made already; ``make``'s exception otherwise."""
        entry = self.get(key)
        if entry is not None:
            return entry
        future = self._pending.get(key)
        if future is None:
            if len(self._pending) >= self.max_pending:
                raise Busy(f"{len(self._pending)} tiles are being made; try again in a moment.")
            self.misses += 1
            loop = asyncio.get_running_loop()
            future = loop.run_in_executor(self.executor, self._make_and_keep, key, make)
            self._pending[key] = future
            future.add_done_callback(lambda done: self._done(key, done))
        # shield: a waiter that is cancelled (its client went away) leaves the tile to be made.
        return await asyncio.shield(future)

    def _done(self, key: Hashable, future: asyncio.Future) -> None:
        self._pending.pop(key, None)
        # Retrieved here: a failure that no waiter saw (all went away) is not logged as lost.
        if not future.cancelled():
            future.exception()

    def _make_and_keep(self, key: Hashable, make: Callable[[], Entry]) -> Entry:
        entry = make()
        self.put(key, entry)
        return entry

    @property
    def pending(self) -> int:
        return len(self._pending)

    def stats(self) -> dict[str, int]:
        with self._lock:
            return {
                "entries": len(self._entries),
                "bytes": self._bytes,
                "limit": self.limit,
                "hits": self.hits,
                "misses": self.misses,
                "pending": len(self._pending),
            }
