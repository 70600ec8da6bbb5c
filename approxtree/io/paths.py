"""Output paths as the user knows them, and the words for why one could not be written.

The bottom of the writing helpers: ``atomic`` (temp file or folder, then a rename),
``own_output`` (is this approxtree's own earlier output?) and ``gdal`` (GDAL's write errors)
all use these, and this module imports none of them.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
from pathlib import Path

from approxtree.errors import StoreError

#: errno values that mean the disk (or the user's quota) has no room.
NO_ROOM = (errno.ENOSPC, errno.EDQUOT)

#: Any temp name of ours (``.NAME.PID.TOKEN.tmp``); group 1 is the target's name.
_ANY_TEMP = re.compile(r"^\.(.+)\.\d+\.[a-z0-9]{8}\.tmp$")


def public_path(path: str | os.PathLike) -> Path:
    """``path`` as the user knows it: each temp folder or file of ours (``.NAME.PID.TOKEN.tmp``)
    in it named as its target (for messages)."""
    parts = []
    for part in Path(path).parts:
        m = _ANY_TEMP.match(part)
        parts.append(m.group(1) if m else part)
    return Path(*parts)


def disk_full(path: str | os.PathLike) -> str:
    """The words for a full disk where ``path`` is written, with the space left there."""
    folder = public_path(Path(path).absolute()).parent
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    try:
        free = f" ({shutil.disk_usage(folder).free:,} bytes free)"
    except OSError:
        free = ""
    return f"the disk is full at {folder}{free}; free some space or write elsewhere"


def why_not_written(target: str | os.PathLike, exc: OSError) -> str:
    """Why ``exc`` kept ``target`` from being written, in words (a full disk says so)."""
    if exc.errno in NO_ROOM:
        return disk_full(target)
    return exc.strerror or str(exc)


def refuse_link(target: str | os.PathLike, what: str = "") -> None:
    """StoreError when ``target`` is a symbolic link (``what`` names it in the message)."""
    target = Path(target)
    if target.is_symlink():
        raise StoreError(
            f"Cannot write {what + ' ' if what else ''}{target}: it is a symbolic link (to "
            f"{os.readlink(target)}); "
            "approxtree never replaces a link nor writes through one, so that nothing it "
            "points to is lost. Give the real path, or a new one."
        )
