"""``approxtree serve``: the web tiles of a tree store, made on request (starlette + uvicorn).

- ``service``: TileService, every kind of tile from the store (no HTTP), with the writers'
  functions, so a served tile equals the file ``approxtree tiles`` writes;
- ``cache``: the responses made, bounded in bytes, one making per tile however many wait;
- ``app``: the URL layout and HTTP (ETag/304, gzip, Cache-Control, CORS, errors as JSON);
- ``runner``: uvicorn on a socket bound first (port 0: any free one), stopped cleanly by
  SIGTERM or Ctrl-C.
"""

from approxtree.tiles.serve.app import create_app
from approxtree.tiles.serve.runner import serve

__all__ = ["create_app", "serve"]
