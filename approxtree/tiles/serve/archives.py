"""PMTiles archives served as they are: imagery and raster-dem tiles read, not made.

``approxtree tiles --format imagery|terrarium|terrain-rgb --out X.pmtiles`` writes one file
whose metadata is the set's TileJSON (``map_tiles.tilejson``: its ``approxtree`` member names
the kind, encoding, tiling and image format). ``open_archive(path)`` reads that metadata and
``Archive.route`` says where the server answers the archive's tiles, the same URLs as tiles
made from a store:

- raster-dem: ``/terrarium/{z}/{x}/{y}.{ext}`` or ``/terrain-rgb/...`` (by its encoding);
- imagery: ``/imagery/{NAME}/webmercator/{z}/{x}/{y}.{ext}``, NAME the file's name without
  ``.pmtiles`` (PMTiles holds Web Mercator tiles only).

``Archive.tile(z, x, y)`` returns the stored bytes (the ``pmtiles`` package's reader over a
memory map: threads may read at once), None for a tile the archive does not hold. Archives
made elsewhere (no ``approxtree`` member) are served by their header's tile type: imagery.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from approxtree.errors import StoreError
from approxtree.tiles.map_tiles import ARCHIVE_SUFFIX, EXTENSIONS, MIME_TYPES

#: PMTiles tile types (header ``tile_type``) the server gives, as image formats.
TILE_TYPES = {2: "png", 3: "jpeg", 4: "webp"}
#: Names an archive's layer may take in a URL (as texture layers: ``service.LAYER_NAME``).
ARCHIVE_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class Route:
    """Where an archive's tiles are served: kind ("imagery", "terrarium", "terrain-rgb"),
    layer (imagery's name, None for raster-dem), scheme (always "webmercator")."""

    kind: str
    layer: str | None
    scheme: str


class Archive:
    """One open PMTiles archive (module docstring). ``close()`` releases its file."""

    def __init__(self, path: Path, reader: Any, file: Any, tilejson: dict, gzipped: bool) -> None:
        self.path = path
        self._reader = reader
        self._file = file
        self.tilejson = tilejson
        #: Whether the tiles are stored gzip-compressed (served with Content-Encoding).
        self.gzipped = gzipped
        meta = tilejson.get("approxtree") or {}
        self.image_format: str = meta["format"]
        kind = meta.get("kind", "imagery")
        if kind == "raster-dem":
            self.route = Route(meta["encoding"], None, "webmercator")
        else:
            self.route = Route("imagery", path.name[: -len(ARCHIVE_SUFFIX)], "webmercator")

    @property
    def media_type(self) -> str:
        return MIME_TYPES[self.image_format]

    @property
    def extension(self) -> str:
        return EXTENSIONS[self.image_format]

    def tile(self, z: int, x: int, y: int) -> bytes | None:
        """The stored bytes of tile (z, x, y); None when the archive has no such tile."""
        if not (0 <= z <= 30 and 0 <= x < 2**z and 0 <= y < 2**z):
            return None
        data = self._reader.get(z, x, y)
        return None if data is None else bytes(data)

    def close(self) -> None:
        self._file.close()


def open_archive(path: str | Path) -> Archive:
    """The archive at ``path`` (a .pmtiles file); StoreError when it is not a readable PMTiles
    v3 archive of PNG, WEBP or JPEG tiles, or its name cannot be a URL."""
    from pmtiles.reader import MmapSource, Reader

    path = Path(path)
    if not path.name.lower().endswith(ARCHIVE_SUFFIX) or not path.is_file():
        raise StoreError(f"{path} is not a PMTiles file (NAME.pmtiles).")
    # Held open for the server's life (closed by ``Archive.close``).
    file = open(path, "rb")
    try:
        reader = Reader(MmapSource(file))
        header = reader.header()
        tilejson = reader.metadata()
    except Exception as exc:  # the pmtiles reader: a damaged or foreign file, in any way
        file.close()
        raise StoreError(f"{path} is not a readable PMTiles archive ({exc}).") from exc
    fmt = TILE_TYPES.get(getattr(header["tile_type"], "value", header["tile_type"]))
    compression = getattr(header["tile_compression"], "value", header["tile_compression"])
    # Compression: 1 none, 2 gzip (others no browser inflates from a header alone).
    if fmt is None or compression not in (1, 2):
        file.close()
        raise StoreError(
            f"{path} holds tiles of type {header['tile_type']} compressed "
            f"{header['tile_compression']}: the server gives PNG, WEBP or JPEG, stored plain "
            "or gzip."
        )
    if not isinstance(tilejson, dict):
        tilejson = {}
    meta = dict(tilejson.get("approxtree") or {"kind": "imagery"})
    meta["format"] = fmt
    dem = meta.get("kind") == "raster-dem"
    if dem and meta.get("encoding") not in ("terrarium", "terrain-rgb"):
        file.close()
        raise StoreError(
            f"{path} is a raster-dem archive of an unknown encoding {meta.get('encoding')!r}."
        )
    tilejson = {**tilejson, "approxtree": meta}
    archive = Archive(path, reader, file, tilejson, compression == 2)
    if archive.route.layer is not None and not ARCHIVE_NAME.match(archive.route.layer):
        archive.close()
        raise StoreError(
            f"Layer names become URLs: {archive.route.layer!r} must be letters, digits, '_', "
            "'.', '-' (64 at most); rename the archive."
        )
    return archive


def open_archives(paths: list[str]) -> dict[Route, Archive]:
    """Route → archive of each path; StoreError when two archives claim the same URLs."""
    out: dict[Route, Archive] = {}
    try:
        for path in paths:
            archive = open_archive(path)
            if archive.route in out:
                archive.close()
                raise StoreError(
                    f"{out[archive.route].path} and {path} would both be served at "
                    f"{url_prefix(archive.route)}: give one of them."
                )
            out[archive.route] = archive
    except StoreError:
        for archive in out.values():
            archive.close()
        raise
    return out


def url_prefix(route: Route) -> str:
    """The URL folder of a route's tiles (module docstring)."""
    if route.kind == "imagery":
        return f"/imagery/{route.layer}/{route.scheme}/"
    return f"/{route.kind}/"
