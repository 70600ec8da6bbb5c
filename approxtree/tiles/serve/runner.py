"""Run the tile server: uvicorn on a socket this process binds (so port 0 works and the URL
printed is the one served), stopped cleanly by SIGTERM or Ctrl-C: no new connection is taken,
the requests under way are answered (for at most ``GRACE_SECONDS``), the worker threads drop
the tiles not started, and ``serve`` returns."""

from __future__ import annotations

import ctypes
import socket
import sys
from collections.abc import Callable

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.tiles.serve.app import create_app

#: Seconds the requests under way get to finish once a shutdown is asked for.
GRACE_SECONDS = 10
#: Connections and requests handled at once; past it uvicorn answers 503.
MAX_CONNECTIONS = 1024
#: glibc malloc arenas: by default 8 per core, each worker thread's tiles growing its own,
#: which took the server's RSS from 348 MB to 521 MB under the load benchmark (NC, 2 cores).
MALLOC_ARENAS = 2


def limit_malloc_arenas(arenas: int = MALLOC_ARENAS) -> None:
    """Cap glibc's malloc arenas (mallopt M_ARENA_MAX) before the worker threads start;
    nothing elsewhere than Linux's glibc."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL("libc.so.6").mallopt(-8, int(arenas))  # -8: M_ARENA_MAX
    except (OSError, AttributeError):
        pass


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on (host, port); StoreError naming the address when it is taken."""
    if not (isinstance(port, int) and 0 <= port <= 65535):
        raise InvalidParameterError(f"port must be 0..65535, got {port!r}.")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise StoreError(
            f"Cannot listen on {host}:{port}: {exc.strerror}; choose another --port."
        ) from exc
    # Listening now: a client that connects before uvicorn accepts waits in the backlog.
    sock.listen(2048)
    return sock


def serve(
    store: str | None,
    textures: str | None = None,
    host: str = "127.0.0.1",
    port: int = 8000,
    cache_bytes: int = 256 << 20,
    workers: int = 2,
    max_pending: int = 256,
    on_ready: Callable[[str], None] | None = None,
    archives: list[str] | None = None,
) -> None:
    """Serve the tiles of ``store`` at http://host:port/ until SIGTERM or Ctrl-C (see
    ``app.create_app`` for the other arguments); ``on_ready(url)`` once it listens."""
    import uvicorn

    limit_malloc_arenas()
    app = create_app(store, textures, cache_bytes, workers, max_pending, archives)
    sock = bind(host, port)
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    config = uvicorn.Config(
        app,
        log_level="warning",
        access_log=False,
        lifespan="on",
        limit_concurrency=MAX_CONNECTIONS,
        timeout_graceful_shutdown=GRACE_SECONDS,
    )
    server = uvicorn.Server(config)
    if on_ready is not None:
        on_ready(f"http://{shown}:{bound}/")
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
