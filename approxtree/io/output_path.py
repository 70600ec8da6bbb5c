"""Checks that an output file or folder can be written, made before the work that fills it.

A build or a bake can take minutes; a PermissionError when the result is finally written
wastes them. These checks create (and remove) a probe file where the output will go, so they
answer for the real file system — a read-only mount, a full quota, a path under a regular file —
whoever the user is (root passes every permission bit, not a read-only mount). A symbolic link
as the output is refused (``paths.refuse_link``): it is never replaced nor written through.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from approxtree.errors import StoreError
from approxtree.io.paths import refuse_link


def _blocking_file(path: Path) -> Path | None:
    """The first ancestor of ``path`` that exists as something other than a folder."""
    for parent in reversed(path.parents):
        if parent.exists() and not parent.is_dir():
            return parent
    return None


def _probe(folder: Path, target: Path, what: str) -> None:
    """StoreError unless a file can be created (and removed) in the existing ``folder``."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".approxtree-probe.", suffix=".tmp", dir=folder)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise StoreError(
            f"Cannot write the {what} {target}: the folder {folder} is not writable ({reason}). "
            "Choose another location or fix the folder's permissions."
        ) from exc
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def _existing_parent(path: Path, what: str) -> Path:
    """The folder that will hold ``path``, or StoreError when it is missing or not a folder."""
    folder = path.parent if str(path.parent) else Path(".")
    blocker = _blocking_file(path)
    if blocker is not None:
        raise StoreError(
            f"Cannot write the {what} {path}: {blocker} is a file, not a folder. "
            "Choose another location."
        )
    if not folder.is_dir():
        raise StoreError(
            f"Cannot write the {what} {path}: the folder {folder} does not exist. Create it "
            "first or choose another location."
        )
    return folder


def check_output_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a Path once a file there can be written (its folder exists and is
    writable, and ``path`` is not a folder); StoreError otherwise. ``what`` names the file in
    the message ("tree file", "image", ...)."""
    p = Path(path)
    folder = _existing_parent(p, what)
    refuse_link(p, f"the {what}")
    if p.is_dir():
        raise StoreError(f"Cannot write the {what} {p}: it is a folder. Give a file name.")
    _probe(folder, p, what)
    return p


def check_output_folder(path: str | os.PathLike, what: str = "folder") -> Path:
    """``path`` as a Path once files can be written into it: an existing writable folder, or
    a new one whose parent exists and is writable (parents are never created); StoreError
    otherwise."""
    p = Path(path)
    refuse_link(p, f"the {what}")
    if p.exists():
        if not p.is_dir():
            raise StoreError(f"Cannot write the {what} {p}: it is a file, not a folder.")
        # A folder is rewritten beside itself and swapped in: both must take new files.
        _probe(p, p, what)
        _probe(_existing_parent(p, what), p, what)
        return p
    _probe(_existing_parent(p, what), p, what)
    return p
