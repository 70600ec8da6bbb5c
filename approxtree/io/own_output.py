"""Whether an existing file or folder is approxtree's own earlier output, before it is replaced.

A command rewrites what it wrote before without a word (running it twice is normal) and
refuses anything else unless the user says ``--overwrite`` (rio's convention): one slip must
not replace a user's DEM, photos or notes. The test reads the thing itself, never its name:

- files carry a mark (writers take it from here: ``GEOTIFF_TAG``, ``png_info``, ``MARK``,
  ``marked_mesh``; ``check_replaceable`` reads it): a GeoTIFF the dataset
  tag ``APPROXTREE_OUTPUT``; a PNG the text chunk ``Software: approxtree``; a JPEG the comment
  ``approxtree``; a GLB ``asset.generator`` "approxtree"; a PLY the header line
  ``comment approxtree``; an OBJ the first line ``# approxtree``; a legacy tree file its magic
  bytes; a zipped tree store its root attributes' format name; a PMTiles archive its
  metadata's ``generator``.
- folders (``FOLDERS``) have a marker file that names approxtree (a tree store's root
  zarr.json, pyramid.json, tileset.json, layer.json, tilejson.json) and hold nothing but the
  names their writer makes: one foreign file (notes.txt) makes the folder the user's.

A symbolic link is never replaced nor written through (either would delete what it points to
or move the output off where the link leads): the user gives the real path. ``--overwrite``
(``overwriting``) lets a command replace what is not its own.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import os
import re
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from approxtree.errors import StoreError
from approxtree.io.paths import refuse_link

#: The word every mark holds.
MARK = "approxtree"
#: GeoTIFF dataset tag of approxtree's rasters; its value names the writer ("fractal", ...).
GEOTIFF_TAG = "APPROXTREE_OUTPUT"
#: Legacy tree files start with these bytes (tree/atree.py's MAGIC).
_ATREE_MAGIC = b"ATREE\x00\r\n"
#: Bytes read to recognise a file's format.
_HEAD = 4096


@dataclass(frozen=True)
class FolderKind:
    """An output folder: its marker file (whose JSON names approxtree, ``_marker_ok``) and
    the relative paths (posix) its writer makes."""

    what: str
    marker: str
    files: re.Pattern[str]


#: The output folders approxtree writes, by kind.
FOLDERS: dict[str, FolderKind] = {
    k.what: k
    for k in (
        # zarr v3: a zarr.json per group and array, chunks under each array's c/ (c alone
        # for a 0-d array).
        FolderKind("tree store", "zarr.json", re.compile(r"([^/]+/)*(zarr\.json|c(/\d+)*)")),
        # pyramid.json and its levels; GDAL side files of reads before PAM was turned off
        # and the .levelK.tif.tmp / .pyramid.json.*.tmp temp files of format-1 bakes killed
        # midway may be there too; re-bakes add levelK.BUILD.tif (deltas, levels rewritten).
        FolderKind(
            "texture pyramid",
            "pyramid.json",
            re.compile(
                r"pyramid\.json|level\d+\.tif(\.aux\.xml)?|\.level\d+\.tif\.tmp|"
                r"level\d+\.[0-9a-f]{32}\.tif|"
                r"\.pyramid\.json\..+\.tmp"
            ),
        ),
        # Explicit ({level}/{node}.glb), implicit (tiles/ and subtrees/ by level/x/y) and
        # terrain (the same under 0/ and 1/, one per hemisphere) tilesets.
        FolderKind(
            "3D Tiles tileset",
            "tileset.json",
            re.compile(
                r"tileset\.json|\d+/\d+\.glb|([01]/)?(tiles/\d+/\d+/\d+\.glb|"
                r"subtrees/\d+/\d+/\d+\.subtree)"
            ),
        ),
        FolderKind(
            "terrain tileset", "layer.json", re.compile(r"layer\.json|\d+/\d+/\d+\.terrain")
        ),
        FolderKind(
            "map tile folder",
            "tilejson.json",
            re.compile(r"tilejson\.json|\d+/\d+/\d+\.(png|webp|jpg)"),
        ),
    )
}

#: File kinds (what a command writes) and the marked formats each may replace.
FILES = {
    "GeoTIFF": ("tiff",),
    "image": ("png", "jpeg"),
    "mesh file": ("glb", "ply", "obj"),
    "tree file": ("atree", "tree zip"),
    "tile archive": ("pmtiles",),
}

#: Paths the user allowed to be replaced whatever they hold (``overwriting``).
_ALLOWED: contextvars.ContextVar[frozenset[str]] = contextvars.ContextVar(
    "approxtree_overwrite", default=frozenset()
)


def _key(path: str | os.PathLike) -> str:
    return os.path.abspath(os.fspath(path))


@contextlib.contextmanager
def overwriting(*paths: str | os.PathLike) -> Iterator[None]:
    """Within the block, ``paths`` may be replaced whatever they hold (``--overwrite``); a
    symbolic link still is not."""
    token = _ALLOWED.set(_ALLOWED.get() | {_key(p) for p in paths})
    try:
        yield
    finally:
        _ALLOWED.reset(token)


def overwrite_allowed(path: str | os.PathLike) -> bool:
    """Whether an ``overwriting`` block allows replacing ``path``."""
    return _key(path) in _ALLOWED.get()


# -- marks written -------------------------------------------------------------------------------


def png_info():
    """PIL ``PngInfo`` holding approxtree's mark (``Software: approxtree``)."""
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_text("Software", MARK)
    return info


def marked_mesh(data: bytes, kind: str) -> bytes:
    """PLY or OBJ bytes with approxtree's mark added (a header comment, a first comment line);
    GLB bytes as they are (their asset.generator is the mark)."""
    if kind == "ply":
        # After "ply" and the "format" line, where strict readers expect them.
        end = data.index(b"\n", data.index(b"\n") + 1) + 1
        return data[:end] + f"comment {MARK}\n".encode() + data[end:]
    if kind == "obj":
        return f"# {MARK}\n".encode() + data
    return data


# -- marks read ----------------------------------------------------------------------------------


def _json(path: Path) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _names_approxtree(doc: object, marker: str) -> bool:
    """Whether a marker file's JSON says approxtree wrote its folder."""
    if not isinstance(doc, dict):
        return False
    if marker == "zarr.json":
        attrs = doc.get("attributes")
        return isinstance(attrs, dict) and str(attrs.get("format", "")).startswith(MARK)
    if marker == "pyramid.json":
        return "build" in doc and isinstance(doc.get("levels"), list)
    if marker == "tileset.json":
        asset = doc.get("asset")
        return isinstance(asset, dict) and asset.get("generator") == MARK
    if marker == "tilejson.json":
        return doc.get("generator") == MARK
    return doc.get("format") == "quantized-mesh-1.0" and MARK in str(doc.get("description"))


def _marker_ok(marker: Path) -> bool:
    """Whether a folder's marker file is approxtree's: its JSON names approxtree, or it does
    not parse (a damaged output of ours: its folder's names decide)."""
    doc = _json(marker)
    return doc is None or _names_approxtree(doc, marker.name)


def foreign_entries(folder: Path, kind: FolderKind) -> list[str]:
    """Relative paths in ``folder`` its writer does not make (sorted; a folder without files
    counts as foreign, and so does any symbolic link)."""
    foreign = []
    for dirpath, dirs, files in os.walk(folder):
        here = Path(dirpath).relative_to(folder)
        for name in sorted(dirs):
            path = Path(dirpath) / name
            if path.is_symlink():
                foreign.append((here / name).as_posix())
                dirs.remove(name)
            elif not any(path.iterdir()):
                foreign.append((here / name).as_posix() + "/")
        for name in files:
            rel = (here / name).as_posix()
            if (Path(dirpath) / name).is_symlink() or not kind.files.fullmatch(rel):
                foreign.append(rel)
    return sorted(foreign)


def _file_format(path: Path) -> str | None:
    """The format of an approxtree-marked file (see FILES), or None when it carries no mark."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HEAD)
    except OSError:
        return None
    if head.startswith(_ATREE_MAGIC):
        return "atree"
    if head.startswith(b"glTF"):
        return "glb" if b'"generator":"approxtree"' in head.replace(b" ", b"") else None
    if head.startswith(b"ply"):
        header = head.split(b"end_header")[0]
        return "ply" if f"comment {MARK}".encode() in header else None
    if head.startswith(f"# {MARK}".encode()):
        return "obj"
    if head.startswith((b"\x89PNG", b"\xff\xd8")):
        return _image_format(path)
    if head.startswith((b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")):
        return "tiff" if _geotiff_tag(path) else None
    if head.startswith(b"PK"):
        return "tree zip" if _zipped_store(path) else None
    if head.startswith(b"PMTiles"):
        return "pmtiles" if _pmtiles_mark(path) else None
    return None


def _image_format(path: Path) -> str | None:
    from PIL import Image

    try:
        with Image.open(path) as im:
            if im.format == "PNG":
                return "png" if im.info.get("Software") == MARK else None
            comment = im.info.get("comment", b"")
            return "jpeg" if comment in (MARK, MARK.encode()) else None
    except (OSError, ValueError, SyntaxError):
        return None


def _geotiff_tag(path: Path) -> bool:
    import rasterio
    from rasterio.errors import RasterioError

    from approxtree.io.gdal import no_side_files

    try:
        with no_side_files(), rasterio.open(path) as ds:
            return GEOTIFF_TAG in ds.tags()
    except RasterioError:
        return False


def _pmtiles_mark(path: Path) -> bool:
    """Whether a PMTiles archive's metadata (its TileJSON) names approxtree as generator."""
    try:
        from pmtiles.reader import MmapSource, Reader

        with open(path, "rb") as f:
            doc = Reader(MmapSource(f)).metadata()
    except Exception:  # any damage: not recognisably ours
        return False
    return isinstance(doc, dict) and doc.get("generator") == MARK


def _zipped_store(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as z:
            doc = json.loads(z.read("zarr.json"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False
    return _names_approxtree(doc, "zarr.json")


# -- the check -----------------------------------------------------------------------------------


def _a(what: str) -> str:
    return ("an " if what[0] in "aeiou" else "a ") + what


def _shown(folder: Path, names: list[str] | None = None) -> str:
    """The first few of ``names`` (default: the folder's entries), for a message."""
    if names is None:
        names = sorted(e.name + ("/" if e.is_dir() else "") for e in folder.iterdir())
    return ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")


def _refuse(path: Path, what: str, problem: str) -> StoreError:
    instead = (
        "a new or empty folder, or --overwrite to replace it (what it holds is deleted)"
        if what in FOLDERS
        else "a new path, or --overwrite to replace it"
    )
    return StoreError(f"Cannot write the {what} {path}: {problem}. Give {instead}.")


def check_replaceable(path: str | os.PathLike, what: str, overwrite: bool | None = None) -> None:
    """StoreError unless writing the ``what`` (a key of FOLDERS or FILES) at ``path`` loses
    nothing: ``path`` is missing, an empty folder, or an earlier approxtree output of that
    kind. ``overwrite`` (None: an ``overwriting`` block decides) allows replacing anything
    but a symbolic link. The message names what is in the way."""
    p = Path(path)
    refuse_link(p, f"the {what}")
    if not p.exists():
        return
    if overwrite is None:
        overwrite = overwrite_allowed(p)
    if overwrite:
        return
    if what in FOLDERS:
        kind = FOLDERS[what]
        if not p.is_dir():
            raise _refuse(p, what, "it is a file, not a folder")
        if not any(p.iterdir()):
            return
        if not (p / kind.marker).is_file():
            raise _refuse(
                p,
                what,
                f"it is a folder that holds no {kind.marker} (it holds {_shown(p)}), so not "
                f"{_a(what)} approxtree wrote, and writing replaces the whole folder",
            )
        if not _marker_ok(p / kind.marker):
            raise _refuse(p, what, f"its {kind.marker} was not written by approxtree")
        foreign = foreign_entries(p, kind)
        if foreign:
            raise _refuse(
                p,
                what,
                f"it holds files that are not part of {_a(what)} ({_shown(p, foreign)}), and "
                "writing replaces the whole folder",
            )
        return
    if p.is_dir():
        raise _refuse(p, what, "it is a folder")
    if _file_format(p) not in FILES[what]:
        raise _refuse(
            p, what, f"it exists and is not {_a(what)} approxtree wrote (no approxtree mark in it)"
        )


def is_own_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder approxtree may replace without being told: empty, or an
    output folder of any kind (FOLDERS) holding nothing foreign."""
    p = Path(path)
    if p.is_symlink() or not p.is_dir():
        return False
    if not any(p.iterdir()):
        return True
    for kind in FOLDERS.values():
        marker = p / kind.marker
        if marker.is_file() and _marker_ok(marker) and not foreign_entries(p, kind):
            return True
    return False
