"""Which kind of approxtree output a path holds, by its content (not its name).

- a folder or zip whose root zarr.json names the tree store format: ``tree-store``;
- a folder with tileset.json (or a tileset.json itself): ``3dtiles``;
- a folder with layer.json: ``quantized-mesh``; a folder with pyramid.json:
  ``texture-pyramid``;
- a folder with tilejson.json, or a PMTiles archive, whose TileJSON names approxtree's kind:
  ``raster-dem`` or ``imagery``;
- a file starting with glTF's, PLY's magic, or OBJ text (``v`` / ``f`` lines): ``mesh``.

A legacy ``.atree`` file is refused (convert it to a store first), so is anything else.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

from approxtree.errors import StoreError

#: Detected kinds, in the order they are tried.
KINDS = (
    "tree-store",
    "3dtiles",
    "quantized-mesh",
    "texture-pyramid",
    "raster-dem",
    "imagery",
    "mesh",
)
#: Map tile kinds named by a TileJSON's ``approxtree.kind``.
MAP_KINDS = ("raster-dem", "imagery")
LEGACY_MAGIC = b"ATREE\x00\r\n"


def _zarr_root(path: Path) -> dict | None:
    """The parsed root zarr.json of a folder or zip store, None when there is none."""
    try:
        if path.is_dir():
            doc = (path / "zarr.json").read_bytes() if (path / "zarr.json").is_file() else None
        elif zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as z:
                doc = z.read("zarr.json") if "zarr.json" in z.namelist() else None
        else:
            doc = None
        return json.loads(doc) if doc is not None else None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise StoreError(
            f"{path} looks like a zarr store but its zarr.json is unreadable: {exc}"
        ) from exc


def _looks_like_obj(head: bytes) -> bool:
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    lines = [ln.strip() for ln in text.splitlines()]
    return any(ln.startswith(("v ", "f ")) for ln in lines) and all(
        not ln or ln[0] in "#vfomgsul" for ln in lines[:-1]
    )


def detect_kind(output: str | os.PathLike) -> str:
    """The kind of ``output`` (one of KINDS); StoreError naming what was found otherwise."""
    path = Path(output)
    if not path.exists():
        raise StoreError(f"{path} does not exist; give an output of approxtree to verify.")
    root = _zarr_root(path)
    if root is not None:
        fmt = (root.get("attributes") or {}).get("format")
        if fmt == "approxtree-tree-store":
            return "tree-store"
        raise StoreError(
            f"{path} is a zarr store but not an approxtree tree store (its root names format "
            f"{fmt!r}: an interrupted write, or another program's store); rebuild it with "
            "`approxtree build`."
        )
    if path.is_dir():
        for name, kind in (
            ("tileset.json", "3dtiles"),
            ("layer.json", "quantized-mesh"),
            ("pyramid.json", "texture-pyramid"),
        ):
            if (path / name).is_file():
                return kind
        if (path / "tilejson.json").is_file():
            return _map_kind(path)
        raise StoreError(
            f"{path} is a folder holding none of zarr.json, tileset.json, layer.json, "
            "pyramid.json or tilejson.json: not an output of approxtree."
        )
    if path.name == "tileset.json":
        return "3dtiles"
    with open(path, "rb") as f:
        head = f.read(4096)
    if head.startswith(b"PMTiles"):
        return _map_kind(path)
    if head.startswith(LEGACY_MAGIC):
        raise StoreError(
            f"{path} is a legacy .atree tree file; verify reads tree stores: convert it with "
            "`approxtree convert` first."
        )
    if head.startswith(b"glTF") or head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return "mesh"
    if _looks_like_obj(head):
        return "mesh"
    raise StoreError(
        f"{path} is not an output of approxtree that verify knows (a tree store, mesh file, "
        "3D Tiles, quantized-mesh, texture pyramid, raster-dem or imagery folder, PMTiles)."
    )


def _map_kind(path: Path) -> str:
    """The kind of a map tile folder or PMTiles archive, by its TileJSON."""
    from approxtree.verify.map_tiles import read_tilejson

    kind = (read_tilejson(path).get("approxtree") or {}).get("kind")
    if kind not in MAP_KINDS:
        raise StoreError(
            f"{path} holds map tiles approxtree did not write (its TileJSON names no "
            "approxtree kind): verify checks raster-dem and imagery tiles of approxtree tiles."
        )
    return kind
