"""Atomic writes: no half-written file, no temp file left behind, the permissions of open()."""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from approxtree.io.atomic import atomic_write

REPO = Path(__file__).resolve().parents[1]


def _temps(folder: Path, name: str) -> list[str]:
    """Temp files and folders of writes to ``name`` (any naming this project ever used)."""
    return sorted(n for n in os.listdir(folder) if n.startswith(f".{name}.") and n.endswith(".tmp"))


def _run_writer(target: Path, die_with: str) -> subprocess.CompletedProcess:
    """A separate process that starts an atomic write of ``target`` and dies in the middle
    (SIGKILL: nothing can clean up; SIGTERM: the write unwinds)."""
    code = f"""
import os, signal
from approxtree.io.atomic import atomic_write
with atomic_write({str(target)!r}) as f:
    f.write(b"half" * 100000)
    f.flush()
    os.kill(os.getpid(), signal.{die_with})
    f.write(b"never")
"""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, cwd=REPO)


@pytest.fixture
def umask():
    """Set the process umask for one test and restore it afterwards."""
    saved = os.umask(0o022)
    os.umask(saved)
    yield lambda mask: os.umask(mask)
    os.umask(saved)


def test_killed_writer_leaves_target_and_next_write_removes_its_temp(tmp_path):
    """SIGKILL in the middle of a write keeps the old file whole; the temp file it leaves is
    removed by the next write to the same target, which then succeeds."""
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    done = _run_writer(target, "SIGKILL")
    assert done.returncode == -signal.SIGKILL, done.stderr
    assert target.read_bytes() == b"old"
    assert len(_temps(tmp_path, "out.bin")) == 1  # the killed writer's half file
    with atomic_write(target) as f:
        f.write(b"new")
    assert target.read_bytes() == b"new"
    assert _temps(tmp_path, "out.bin") == []
    assert sorted(os.listdir(tmp_path)) == ["out.bin"]


def test_terminated_writer_cleans_up_and_still_dies_by_sigterm(tmp_path):
    """SIGTERM in the middle of a write removes the temp file and keeps the old file; the
    process still ends by SIGTERM."""
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    done = _run_writer(target, "SIGTERM")
    assert done.returncode == -signal.SIGTERM, done.stderr
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["out.bin"]


def test_temps_of_live_writers_and_other_targets_are_kept(tmp_path):
    """Only temp files of dead writers to the same target go: a live writer's temp, another
    target's temp (even one whose name extends this target's) and unrelated files stay."""
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], text=True, capture_output=True
    ).stdout.strip()
    live = str(os.getppid())
    keep = [
        f".out.bin.{live}.abcdefgh.tmp",  # a running process is still writing it
        f".out.bin.x.{dead}.abcdefgh.tmp",  # a write to "out.bin.x"
        ".out.bin.notes.tmp",  # not a temp name of ours
        "out.bin.tmp",
    ]
    gone = [f".out.bin.{dead}.abcdefgh.tmp", f".out.bin.{dead}.zz11zz11.tmp"]
    for name in keep + gone:
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / f".out.bin.{dead}.folder01.tmp").mkdir()  # a dead bake's temp folder
    (tmp_path / f".out.bin.{dead}.folder01.tmp" / "level0.tif").write_bytes(b"x")
    with atomic_write(tmp_path / "out.bin") as f:
        f.write(b"new")
    assert sorted(os.listdir(tmp_path)) == sorted([*keep, "out.bin"])
    from approxtree.io.atomic import temp_pattern

    assert temp_pattern("out.bin").match(gone[0])


def test_stale_temp_with_this_process_pid_is_removed(tmp_path):
    """A temp name carrying this process's PID but not being written now was left by an
    earlier process with the same PID (PIDs are reused): it goes too."""
    stale = tmp_path / f".out.bin.{os.getpid()}.abcdefgh.tmp"
    stale.write_bytes(b"x")
    with atomic_write(tmp_path / "out.bin") as f:
        f.write(b"new")
    assert sorted(os.listdir(tmp_path)) == ["out.bin"]


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_new_files_get_the_umask_permissions(tmp_path, umask, mask):
    """A new file gets 0666 & ~umask, as a plain open() gives (was: always 0600)."""
    umask(mask)
    with atomic_write(tmp_path / "new.bin") as f:
        f.write(b"x")
    with open(tmp_path / "plain.bin", "wb") as f:
        f.write(b"x")
    mode = stat.S_IMODE(os.stat(tmp_path / "new.bin").st_mode)
    assert mode == 0o666 & ~mask == stat.S_IMODE(os.stat(tmp_path / "plain.bin").st_mode)


@pytest.mark.parametrize("mode", [0o755, 0o600, 0o640, 0o444])
def test_replacing_keeps_the_file_mode(tmp_path, umask, mode):
    """Replacing an existing file keeps its mode, whatever the umask."""
    umask(0o022)
    target = tmp_path / "run.sh"
    target.write_bytes(b"old")
    target.chmod(mode)
    with atomic_write(target) as f:
        f.write(b"new")
    assert stat.S_IMODE(os.stat(target).st_mode) == mode
    assert target.read_bytes() == b"new"


def test_tree_and_mesh_files_follow_the_umask(tmp_path, umask):
    """The writers built on atomic_write (tree file, mesh file) give umask permissions."""
    from approxtree import ApproximationTree
    from approxtree.datasets import fractal_terrain
    from approxtree.io.mesh_file import write_mesh

    umask(0o022)
    tree = ApproximationTree.build(fractal_terrain(9, seed=1), epsilon=1.0, max_points=9)
    tree.save(tmp_path / "t.zarr.zip")
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1]], dtype=float)
    write_mesh(tmp_path / "m.ply", v, np.array([[0, 1, 2]]))
    for name in ("t.zarr.zip", "m.ply"):
        assert stat.S_IMODE(os.stat(tmp_path / name).st_mode) == 0o644, name


def test_gitignore_matches_temp_names():
    """The temp files and folders of atomic writes are ignored by git."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    names = [".demo.atree.4242.abcdefgh.tmp", "out/.pyr.4242.abcdefgh.tmp", ".m.ply.1.a1b2c3d4.tmp"]
    for name in names:
        done = subprocess.run(["git", "check-ignore", "-q", "--no-index", name], cwd=REPO)
        assert done.returncode == 0, name


def test_a_write_that_cannot_be_done_is_a_store_error(tmp_path):
    """A target the rename cannot replace (here a folder) is a StoreError naming it, not an
    OSError, and leaves no temp file."""
    from approxtree import StoreError

    (tmp_path / "out.bin").mkdir()
    with (
        pytest.raises(StoreError, match=r"Cannot replace .*out\.bin"),
        atomic_write(tmp_path / "out.bin") as f,
    ):
        f.write(b"x")
    assert os.listdir(tmp_path) == ["out.bin"]


# -- folders: never through a link, never a folder of the user's; a full disk -------------------


def test_a_folder_swap_never_follows_a_symlink(tmp_path):
    """atomic_directory of a symbolic link is refused and what it points to is kept (it took
    the link's realpath and emptied the target)."""
    from approxtree import StoreError
    from approxtree.io.atomic import atomic_directory

    real = tmp_path / "real"
    real.mkdir()
    (real / "tileset.json").write_text('{"asset": {"generator": "approxtree"}}')
    (tmp_path / "link").symlink_to(real)
    with pytest.raises(StoreError, match="symbolic link"), atomic_directory(tmp_path / "link"):
        pass
    assert os.listdir(real) == ["tileset.json"] and (tmp_path / "link").is_symlink()
    assert sorted(os.listdir(tmp_path)) == ["link", "real"]


def test_a_folder_of_the_users_is_replaced_only_when_allowed(tmp_path):
    """atomic_directory refuses to swap out a folder holding files approxtree did not write;
    within an ``overwriting`` block (--overwrite) it replaces it; an empty folder and an
    approxtree output folder are replaced without a word."""
    from approxtree import StoreError
    from approxtree.io.atomic import atomic_directory
    from approxtree.io.own_output import overwriting

    mine = tmp_path / "mine"
    (mine / "mydata").mkdir(parents=True)
    (mine / "mydata" / "keep.txt").write_text("keep")
    with pytest.raises(StoreError, match="did not write"), atomic_directory(mine) as tmp:
        (tmp / "layer.json").write_text("{}")
    assert (mine / "mydata" / "keep.txt").read_text() == "keep"
    with overwriting(mine), atomic_directory(mine) as tmp:
        (tmp / "new.txt").write_text("new")
    assert os.listdir(mine) == ["new.txt"]
    # Outside the block the permission is gone again.
    with pytest.raises(StoreError), atomic_directory(mine):
        pass
    empty = tmp_path / "empty"
    empty.mkdir()
    with atomic_directory(empty) as tmp:
        (tmp / "pyramid.json").write_text('{"build": "b", "levels": []}')
    with atomic_directory(empty) as tmp:
        (tmp / "pyramid.json").write_text('{"build": "c", "levels": []}')
    assert "c" in (empty / "pyramid.json").read_text()
    assert sorted(os.listdir(tmp_path)) == ["empty", "mine"]


@pytest.mark.parametrize("step", ["write", "fsync"])
def test_a_full_disk_is_a_store_error_that_says_so(tmp_path, monkeypatch, step):
    """ENOSPC while writing (or flushing) a file is one StoreError saying the disk is full at
    the folder (it was an OSError traceback); the temp goes, the old file stays."""
    import errno

    from approxtree import StoreError

    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def no_room(*args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    if step == "fsync":
        monkeypatch.setattr("approxtree.io.atomic.os.fsync", no_room)
    with pytest.raises(StoreError, match=f"disk is full at {tmp_path}"), atomic_write(target) as f:
        if step == "write":
            no_room()
        f.write(b"new")
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["out.bin"]


def test_other_errors_of_the_callers_block_pass_as_they_are(tmp_path):
    """An OSError of the caller's own (reading a missing input) is not reworded as a failed
    write: only errors of writing become StoreErrors."""
    with pytest.raises(FileNotFoundError), atomic_write(tmp_path / "out.bin"):
        open(tmp_path / "missing.txt", "rb")
    assert os.listdir(tmp_path) == []


def test_terminated_zip_store_write_removes_its_temp_folder(tmp_path):
    """A zip store is written as a temp folder first: SIGTERM (twice, as ``timeout`` sends it)
    unwinds that write too, leaving the old zip and no temp folder (a killed convert left it)."""
    target = tmp_path / "t.zarr.zip"
    target.write_bytes(b"old")
    code = f"""
import os, signal
from approxtree.tree.zarr_store import writing
with writing({str(target)!r}, {{}}) as root:
    os.kill(os.getpid(), signal.SIGTERM)
    os.kill(os.getpid(), signal.SIGTERM)
    root.create_group("never")
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, cwd=REPO)
    assert done.returncode == -signal.SIGTERM, done.stderr
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["t.zarr.zip"]
