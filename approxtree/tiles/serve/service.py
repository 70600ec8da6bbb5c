"""TileService: every tile the server offers, made from a tree store (and texture pyramids).

No HTTP here: each method takes a tile's address and returns a cache ``Entry`` (media type,
bytes), made by the same functions ``approxtree tiles`` writes with, with the same defaults,
so that a served tile equals the written file byte for byte:

- 3D Tiles: ``tileset3d.tile_maker`` (``encode(node)`` per GLB; tileset.json from every node's
  content, ``tileset3d.tileset_document``: the first request walks the whole tree);
- quantized-mesh: ``quantized_mesh.terrain_job`` + ``make_tile``, the store's ε as leaf error;
- imagery: ``imagery.ImageryTiles`` per layer and tiling; raster-dem: ``raster_dem.DemTiles``;
- PMTiles archives (``archives``): their imagery or raster-dem tiles read as stored, at the
  URLs of the same tiles made from a store (an archive's set wins over the store's).

Each kind is opened on first use (a store without a CRS still serves 3D Tiles); a kind that
cannot be served, or an address outside its tiles, raises ``NotServed`` (HTTP 404) with the
reason. Layers: ``--textures DIR`` is one pyramid (a layer named after DIR) or a folder of
pyramid folders (one layer each, by name); 3D Tiles embed the first layer's texture. Without
a store (archives only) the store's kinds raise NotServed.
"""

from __future__ import annotations

import json
import re
import threading
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from approxtree.errors import ApproxTreeError, StoreError
from approxtree.textures.detail import open_drape
from approxtree.tiles.map_tiles import EXTENSIONS, MIME_TYPES, tile_plan, tilejson
from approxtree.tiles.quantized_mesh import layer_json, make_tile, terrain_job
from approxtree.tiles.serve.archives import Archive, Route, open_archives, url_prefix
from approxtree.tiles.serve.cache import Entry, TileCache
from approxtree.tiles.tileset3d import tile_maker, tile_uri, tileset_document
from approxtree.tiles.web_maps import open_map_tiles

#: Layer names a URL may carry.
LAYER_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
GLB = "model/gltf-binary"
JSON = "application/json"
TERRAIN = "application/vnd.quantized-mesh"


class NotServed(ApproxTreeError):
    """The server has no such resource (HTTP 404): an address outside the tiles, or a kind
    of tile this store cannot give (the message says why)."""


def find_layers(textures: str | None) -> dict[str, Path]:
    """Layer name → pyramid folder of ``--textures`` (module docstring); StoreError when it
    holds no pyramid."""
    if textures is None:
        return {}
    root = Path(textures)
    if (root / "pyramid.json").is_file():
        folders = {root.resolve().name: root}
    elif root.is_dir():
        folders = {p.name: p for p in sorted(root.iterdir()) if (p / "pyramid.json").is_file()}
    else:
        folders = {}
    if not folders:
        raise StoreError(
            f"{textures} is neither a texture pyramid nor a folder of them; bake one with "
            "approxtree bake STORE --out DIR."
        )
    bad = [name for name in folders if not LAYER_NAME.match(name)]
    if bad:
        raise StoreError(
            f"Layer names become URLs: {bad} must be letters, digits, '_', '.', '-' "
            "(64 at most); rename the pyramid folders."
        )
    return folders


class TileService:
    """The tiles of one tree store and of PMTiles archives (module docstring); ``store`` None
    for archives only. ``cache``: where the tiles a tileset.json walk makes are kept too."""

    def __init__(
        self, store: str | None, textures: str | None = None, archives: list[str] | None = None
    ) -> None:
        from approxtree.tree.store import open_store

        if store is None and not archives:
            raise StoreError("Nothing to serve: give a tree store, PMTiles archives or both.")
        self.store = store
        self.name = Path(str(store).rstrip("/")).name if store is not None else "archives"
        #: The store's terrain (its heights read by windows as tiles ask for them).
        self.terrain = open_store(store).terrain() if store is not None else None
        self.layer_folders = find_layers(textures)
        self.archives: dict[Route, Archive] = open_archives(list(archives or []))
        clash = [r.layer for r in self.archives if r.layer in self.layer_folders]
        if clash:
            self.close()
            raise StoreError(
                f"Imagery layer {clash[0]!r} is both a texture pyramid and an archive; rename "
                "one of them."
            )
        self._lock = threading.RLock()
        self._opened: dict[Any, Any] = {}

    def close(self) -> None:
        """Release the archives' files."""
        for archive in self.archives.values():
            archive.close()

    def _need_store(self, what: str) -> str:
        """The store's path; NotServed when the server has none."""
        if self.store is None:
            raise NotServed(f"No {what}: the server was started with PMTiles archives only.")
        return self.store

    def _open(self, key: Any, opener: Any) -> Any:
        """The object ``opener()`` makes, once per key (threads share it); an ApproxTreeError
        it raises (but a StoreError) becomes NotServed with the same message, kept."""
        with self._lock:
            if key not in self._opened:
                try:
                    self._opened[key] = opener()
                except (NotServed, StoreError):
                    # Not kept: a damaged store may be repaired while the server runs.
                    raise
                except ApproxTreeError as exc:
                    self._opened[key] = NotServed(str(exc))
            found = self._opened[key]
        if isinstance(found, NotServed):
            raise found
        return found

    # -- 3D Tiles ---------------------------------------------------------------------------

    def _tiles3d(self) -> tuple[Any, Any, Any]:
        def opener():
            from approxtree.tree import load_tree

            tree = load_tree(self._need_store("3D Tiles"), verify=False)
            first = next(iter(self.layer_folders.values()), None)
            writer, frame = tile_maker(tree, textures=first)
            return tree, writer, frame

        return self._open("3dtiles", opener)

    def glb(self, level: int, node: int) -> Entry:
        """Node ``node``'s GLB (its level must be ``level``, as tileset.json names it)."""
        tree, writer, _ = self._tiles3d()
        if not (0 <= node < len(tree.errors)) or int(tree.levels[node]) != level:
            raise NotServed(f"The tileset has no tile {level}/{node}.glb.")
        made = writer.encode(node)
        if made is None:
            raise NotServed(f"Node {node} has no triangle, so no content.")
        return Entry.made(GLB, made[0])

    def tileset(self, cache: TileCache, executor: Executor, workers: int) -> Entry:
        """tileset.json: every node's GLB made (on ``workers`` threads, each kept in
        ``cache``) for the contents' bounds and errors, then the document."""
        tree, writer, frame = self._tiles3d()
        n = len(tree.errors)

        def part(nodes: range) -> list:
            out = []
            for i in nodes:
                made = writer.encode(i)
                if made is not None:
                    cache.put(
                        ("3dtiles", tile_uri(int(tree.levels[i]), i)), Entry.made(GLB, made[0])
                    )
                out.append(None if made is None else made[1])
            return out

        # Parts on the other worker threads, the first on this one (itself a worker: waiting
        # for all parts from here would leave none to run them with one worker).
        step = -(-n // max(workers, 1))
        starts = range(0, n, step)
        futures = [executor.submit(part, range(a, min(a + step, n))) for a in starts[1:]]
        contents = part(range(0, min(step, n))) + [c for f in futures for c in f.result()]
        return Entry.made(JSON, tileset_document(tree, frame, contents))

    # -- quantized-mesh ---------------------------------------------------------------------

    def _terrain_job(self) -> tuple[Any, dict[int, set[tuple[int, int]]], Any]:
        def opener():
            from approxtree.tiles.quantized_mesh import DEFAULT_LEAF_ERROR
            from approxtree.tree.loading import tree_epsilon

            leaf = tree_epsilon(self._need_store("quantized-mesh terrain")) or DEFAULT_LEAF_ERROR
            job, plan = terrain_job(self.terrain, leaf_error=leaf)
            return job, {z: set(tiles) for z, tiles in plan.items()}, plan

        return self._open("terrain", opener)

    def layer_json(self) -> Entry:
        job, _, plan = self._terrain_job()
        layer = layer_json(job.sampler, plan, False, self.name)
        return Entry.made(JSON, json.dumps(layer, indent=1).encode())

    def terrain_tile(self, z: int, x: int, y: int) -> Entry:
        job, available, _ = self._terrain_job()
        if (x, y) not in available.get(z, ()):
            raise NotServed(f"The terrain has no tile {z}/{x}/{y} (see layer.json).")
        data, _ = make_tile(job, z, x, y)
        return Entry.made(TERRAIN, data, gzipped=True)

    # -- imagery and raster-dem -------------------------------------------------------------

    def _map_source(self, kind: str, layer: str | None, scheme: str, fmt: str) -> tuple[Any, Any]:
        """(source, {zoom: set of (x, y)}) of a map tile set."""

        def opener():
            if kind != "imagery":
                self._need_store(f"{kind} tiles")
            if kind == "imagery":
                if layer not in self.layer_folders:
                    names = ", ".join(self.layer_folders) or "none: start with --textures DIR"
                    raise NotServed(f"No imagery layer {layer!r} (layers: {names}).")
                folder = self.layer_folders[layer]
                pyramid = self._open(("pyramid", layer), lambda: open_drape(folder, self.terrain))
                source = open_map_tiles(kind, self.terrain, pyramid, scheme, image_format=fmt)
            else:
                source = open_map_tiles(kind, self.terrain, image_format=fmt)
            return source, {z: set(t) for z, t in tile_plan(source).items()}

        return self._open((kind, layer, scheme, fmt), opener)

    def map_tile(
        self, kind: str, layer: str | None, scheme: str, z: int, x: int, y: int, ext: str
    ) -> Entry:
        """An imagery or raster-dem tile; ``ext`` picks the image format (png, webp, jpg)."""
        archive = self.archives.get(Route(kind, layer, scheme))
        if archive is not None:
            return self._archive_tile(archive, z, x, y, ext)
        fmt = {v: k for k, v in EXTENSIONS.items()}.get(ext)
        if fmt is None or (kind != "imagery" and fmt == "jpeg"):
            raise NotServed(f"No {kind} tiles as .{ext}.")
        source, available = self._map_source(kind, layer, scheme, fmt)
        if (x, y) not in available.get(z, ()):
            raise NotServed(f"The {kind} set has no tile {z}/{x}/{y} (see its tilejson.json).")
        return Entry.made(MIME_TYPES[fmt], source.tile(z, x, y))

    @staticmethod
    def _archive_tile(archive: Archive, z: int, x: int, y: int, ext: str) -> Entry:
        """A tile of an archive, as stored (its format is the archive's one)."""
        if ext != archive.extension:
            raise NotServed(f"{archive.path.name} holds .{archive.extension} tiles, not .{ext}.")
        data = archive.tile(z, x, y)
        if data is None:
            raise NotServed(f"{archive.path.name} has no tile {z}/{x}/{y}.")
        return Entry.made(archive.media_type, data, gzipped=archive.gzipped)

    def map_tilejson(self, kind: str, layer: str | None, scheme: str, base: str) -> bytes:
        """The TileJSON of a tile set, its ``tiles`` the absolute URL template under ``base``."""
        archive = self.archives.get(Route(kind, layer, scheme))
        if archive is not None:
            doc = dict(archive.tilejson)
            doc["tiles"] = [base + "{z}/{x}/{y}." + archive.extension]
            return json.dumps(doc, indent=1).encode()
        source, available = self._map_source(kind, layer, scheme, "png")
        plan = {z: sorted(t) for z, t in available.items()}
        doc = tilejson(source, layer or kind, plan)
        doc["tiles"] = [base + doc["tiles"][0]]
        return json.dumps(doc, indent=1).encode()

    @property
    def archive_urls(self) -> dict[str, str]:
        """Archive file name → the URL folder of its tiles."""
        return {a.path.name: url_prefix(route) for route, a in self.archives.items()}

    @property
    def layers(self) -> list[str]:
        """The imagery layers' names, in URL order (the first is 3D Tiles' texture)."""
        return list(self.layer_folders)
