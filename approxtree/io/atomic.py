"""Atomic writes: a temp file (or folder) beside the target, then one rename over the target.

An interrupted write leaves the previous file (or nothing) in place, never half a file.

- Temp names are ``.NAME.PID.TOKEN.tmp`` (PID: the writing process). A write removes the temp
  files its own failure leaves (any exception, KeyboardInterrupt, SIGTERM in the main thread);
  a process killed outright (SIGKILL, power loss) cannot, so the next write to the same target
  removes the temp files of writers that no longer run.
- Permissions are those a plain ``open()`` would give: a new file gets 0666 & ~umask (a new
  folder 0777 & ~umask), and a replaced file or folder keeps its mode.
- A symbolic link is never replaced nor written through (what it points to would be lost),
  and a folder is replaced only when it is empty or approxtree's own output
  (``own_output.is_own_folder``) unless an ``own_output.overwriting`` block allows it.
- Any failure is a StoreError saying what could not be written and why; a full disk says so,
  with the folder (``disk_full``). The temp file or folder goes, the old target stays.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import secrets
import shutil
import signal
import stat
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from approxtree.errors import StoreError
from approxtree.io.own_output import is_own_folder, overwrite_allowed
from approxtree.io.paths import NO_ROOM, refuse_link, why_not_written

_TOKEN_CHARS = "abcdefghijklmnopqrstuvwxyz0123456789"

#: Temp paths this process is writing now: a temp name with our own PID that is not listed
#: here was left by an earlier process that had the same PID (PIDs are reused).
_ACTIVE: set[Path] = set()
_ACTIVE_LOCK = threading.Lock()


def temp_pattern(name: str) -> re.Pattern[str]:
    """The temp names of writes to a target called ``name``; group 1 is the writer's PID."""
    return re.compile(rf"^\.{re.escape(name)}\.(\d+)\.[a-z0-9]{{8}}\.tmp$")


def _temp_path(target: Path) -> Path:
    token = "".join(secrets.choice(_TOKEN_CHARS) for _ in range(8))
    return target.with_name(f".{target.name}.{os.getpid()}.{token}.tmp")


@contextlib.contextmanager
def _registered(path: Path) -> Iterator[None]:
    with _ACTIVE_LOCK:
        _ACTIVE.add(path)
    try:
        yield
    finally:
        with _ACTIVE_LOCK:
            _ACTIVE.discard(path)


def _in_use(path: Path, pid: int) -> bool:
    """Whether the writer named in a temp name may still be writing it."""
    if pid == os.getpid():
        with _ACTIVE_LOCK:
            return path in _ACTIVE
    if os.name == "nt":  # os.kill(pid, 0) would end the process there: never guess
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        # Another user's process runs under that PID (or the name is not ours): keep it.
        return True
    return True


def remove_stale_temps(target: str | os.PathLike) -> list[Path]:
    """Remove the temp files and folders of dead writers to ``target``; returns what went."""
    target = Path(target)
    folder = target.parent
    pattern = temp_pattern(target.name)
    removed: list[Path] = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = pattern.match(name)
        path = folder / name
        if m is None or _in_use(path, int(m.group(1))):
            continue
        # A dead writer's leftover: a half-written file, or a folder (built or swapped out).
        with contextlib.suppress(OSError):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
            removed.append(path)
    return removed


class _Terminated(BaseException):
    """SIGTERM received during a write: unwinds like KeyboardInterrupt so temp files go."""


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """Within the block, SIGTERM raises (so ``finally`` and ``except`` clean up); after the
    cleanup the process still dies by SIGTERM. Only in the main thread, and only where no
    handler of the host program is installed."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    ):
        yield
        return

    def handler(signum: int, frame: object) -> None:
        # Once: a second SIGTERM (``timeout`` signals the process group too) raised again
        # inside the cleanup, left the temp file and crashed the process (segfault).
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise _Terminated

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    except _Terminated:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        raise
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _check_folder(target: Path) -> Path:
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise StoreError(f"Cannot write {target}: the folder {folder} does not exist.")
    return folder


#: errno values that can only come from writing (the block's own OSErrors of these kinds
#: become StoreErrors about the target).
_WRITE_ERRNOS = (*NO_ROOM, errno.EFBIG, errno.EROFS, errno.EIO)


@contextlib.contextmanager
def _os_errors(what: str, target: Path | None = None) -> Iterator[None]:
    """An OSError of the block as a StoreError saying what could not be done and why."""
    try:
        yield
    except OSError as exc:
        why = why_not_written(target, exc) if target is not None else exc.strerror or exc
        raise StoreError(f"{what}: {why}.") from exc


@contextlib.contextmanager
def _write_errors(target: Path, tmp: Path) -> Iterator[None]:
    """The caller's block writing ``tmp``: an OSError of writing (a full disk, a read-only
    file system) or one about a path inside ``tmp`` becomes a StoreError about ``target``;
    other OSErrors are the caller's own (a missing input) and pass as they are."""
    try:
        yield
    except OSError as exc:
        name = str(exc.filename or "")
        if exc.errno in _WRITE_ERRNOS or (name and name.startswith(str(tmp))):
            raise StoreError(f"Cannot write {target}: {why_not_written(target, exc)}.") from exc
        raise


def _existing_mode(path: Path) -> int | None:
    """Permission bits of ``path`` when it exists (following links), else None."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except (FileNotFoundError, NotADirectoryError):
        return None


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """Open a binary temp file that replaces ``path`` only when the block finishes cleanly."""
    target = Path(path)
    _check_folder(target)
    refuse_link(target)
    remove_stale_temps(target)
    keep_mode = _existing_mode(target)
    tmp = _temp_path(target)
    with _sigterm_unwinds(), _registered(tmp):
        try:
            # O_EXCL with 0666: the kernel applies the umask, as for a plain open().
            with _os_errors(f"Cannot write {target}", target):
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            with _write_errors(target, tmp), os.fdopen(fd, "wb") as f:
                if keep_mode is not None:
                    os.chmod(tmp, keep_mode)
                yield f
                f.flush()
                os.fsync(f.fileno())
            with _os_errors(f"Cannot replace {target}", target):
                os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError, TypeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p]
    renameat2.argtypes += [ctypes.c_uint]
    rc = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """A temp folder beside ``path`` that replaces the folder ``path`` when the block finishes
    cleanly (all or nothing); on failure it is removed and ``path`` is left as it was.

    An existing ``path`` is swapped out in one step where the OS can (Linux), else renamed
    aside and back in; the old folder is then removed. It must be empty or approxtree's own
    output holding nothing foreign (``own_output``), unless an ``overwriting`` block allows
    it; a symbolic link is refused (its target is never emptied). Callers check the same
    beforehand with ``own_output.check_replaceable``, so that no work is wasted.
    """
    target = Path(path)
    _check_folder(target)
    refuse_link(target)
    remove_stale_temps(target)
    keep_mode = _existing_mode(target)
    if keep_mode is not None and not target.is_dir():
        raise StoreError(f"Cannot write the folder {target}: a file of that name exists.")
    if keep_mode is not None and not (is_own_folder(target) or overwrite_allowed(target)):
        raise StoreError(
            f"Cannot write the folder {target}: it holds files approxtree did not write, and "
            "writing replaces the whole folder. Give a new or empty folder."
        )
    tmp = _temp_path(target)
    aside = _temp_path(target)
    with _sigterm_unwinds(), _registered(tmp), _registered(aside):
        try:
            # mkdir with 0777: the kernel applies the umask, as for a plain mkdir.
            with _os_errors(f"Cannot write {target}", target):
                os.mkdir(tmp, 0o777)
            if keep_mode is not None:
                os.chmod(tmp, keep_mode)
            with _write_errors(target, tmp):
                yield tmp
            with _os_errors(f"Cannot replace {target}", target):
                if keep_mode is None:
                    os.rename(tmp, target)
                elif not _exchange(tmp, target):
                    os.rename(target, aside)
                    try:
                        os.rename(tmp, target)
                    except BaseException:
                        os.rename(aside, target)
                        raise
                    tmp = aside
            # ``tmp`` now holds the old folder (or nothing).
            shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temp file path beside ``path`` for a library that writes by name (GDAL, ...): the file
    written there replaces ``path`` when the block finishes cleanly; on failure it is removed
    and ``path`` is left as it was."""
    target = Path(path)
    _check_folder(target)
    refuse_link(target)
    remove_stale_temps(target)
    keep_mode = _existing_mode(target)
    tmp = _temp_path(target)
    with _sigterm_unwinds(), _registered(tmp):
        try:
            with _write_errors(target, tmp):
                yield tmp
            with _os_errors(f"Cannot replace {target}", target):
                if keep_mode is not None:
                    os.chmod(tmp, keep_mode)
                with open(tmp, "rb+") as f:
                    os.fsync(f.fileno())
                os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise


@contextlib.contextmanager
def scratch_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temp file path beside ``path`` for an intermediate file, always removed at the end;
    named like the temp files of writes to ``path``, so a killed writer's leftover goes with
    the next write to ``path``."""
    tmp = _temp_path(Path(path))
    with _registered(tmp):
        try:
            yield tmp
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
