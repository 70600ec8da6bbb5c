"""The legacy .atree file (read only): checksums catch corruption and truncation; tree stores
are written atomically and .atree paths are refused."""

from __future__ import annotations

import os

import numpy as np
import pytest
from atree_writer import encode_record, write_atree

from approxtree import ApproximationTree, InvalidParameterError, StoreError
from approxtree.datasets import fractal_terrain
from approxtree.tree.atree import TreeFile, decode_record


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A small tree written as a legacy .atree file (tests/atree_writer.py), with its bytes."""
    tree = ApproximationTree.build(
        fractal_terrain(65, seed=4, relief=100.0), epsilon=1.0, max_points=25
    )
    path = tmp_path_factory.mktemp("store") / "tree.atree"
    write_atree(tree, path)
    return tree, path, path.read_bytes()


def _corrupt(tmp_path, data: bytes, offset: int) -> os.PathLike:
    bad = bytearray(data)
    bad[offset] ^= 0xFF
    path = tmp_path / "bad.atree"
    path.write_bytes(bytes(bad))
    return path


@pytest.mark.parametrize("where", ["header", "terrain", "nodes", "patch_index", "patch"])
def test_flipped_byte_is_detected(saved, tmp_path, where):
    """One flipped byte anywhere — header, any section, a patch — is a StoreError on load."""
    _, path, data = saved
    f = TreeFile(path)
    if where == "header":
        offset = 30
    elif where == "patch":
        offset = f.patch_span(3)[0] + 2
    else:
        start, length = f.section_span(where)
        offset = start + length // 2
    with pytest.raises(StoreError, match="corrupted"):
        ApproximationTree.load(_corrupt(tmp_path, data, offset))


def test_corrupted_patch_is_caught_when_read_alone(saved, tmp_path):
    """Without eager verification a corrupted patch fails when that node's patch is read."""
    _, path, data = saved
    f = TreeFile(path)
    offset = f.patch_span(5)[0] + 1
    tree = ApproximationTree.load(_corrupt(tmp_path, data, offset), verify=False)
    assert tree.node(4).patch.error == tree.errors[4]  # an intact neighbour loads fine
    with pytest.raises(StoreError, match="patch of node 5"):
        _ = tree.node(5).patch


@pytest.mark.parametrize("keep", [0, 10, 100, -1])
def test_truncated_file_is_detected(saved, tmp_path, keep):
    """Truncated files (empty, mid-header, mid-data, one byte short) are StoreErrors."""
    _, _, data = saved
    path = tmp_path / "short.atree"
    path.write_bytes(data[:keep] if keep >= 0 else data[:-1])
    with pytest.raises(StoreError):
        ApproximationTree.load(path)


def test_other_files_and_versions_are_refused(saved, tmp_path):
    """A non-tree file and a future format version are refused with a clear message."""
    _, _, data = saved
    other = tmp_path / "x.atree"
    other.write_bytes(b"GeoTIFF? no." * 10)
    with pytest.raises(StoreError, match="not an approxtree tree file"):
        ApproximationTree.load(other)
    future = bytearray(data)
    future[8] = 99
    other.write_bytes(bytes(future))
    with pytest.raises(StoreError, match="version 99"):
        ApproximationTree.load(other)
    with pytest.raises(StoreError, match="does not exist"):
        ApproximationTree.load(tmp_path / "missing.atree")


def test_interrupted_save_leaves_the_old_file_intact(saved, tmp_path, monkeypatch):
    """A save that fails midway keeps the previous tree file and leaves no temp file."""
    import approxtree.tree.tree_store as ts

    tree, _, _ = saved
    path = tmp_path / "keep.zarr.zip"
    tree.save(path)
    data = path.read_bytes()
    calls = {"n": 0}
    original = ts.write_array

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 10:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(ts, "write_array", failing)
    with pytest.raises(KeyboardInterrupt):
        tree.save(path)
    assert path.read_bytes() == data
    assert os.listdir(tmp_path) == ["keep.zarr.zip"]


def test_atree_paths_are_refused_when_saving(saved, tmp_path):
    """The legacy .atree file is read only: saving to a .atree path is an
    InvalidParameterError naming the tree store forms, and writes nothing."""
    tree, _, _ = saved
    with pytest.raises(InvalidParameterError, match=r"no longer writes.*NAME\.zarr"):
        tree.save(tmp_path / "t.atree")
    assert os.listdir(tmp_path) == []


def test_one_patch_loads_on_its_own(saved):
    """A single node's patch can be read from the file without loading the others."""
    tree, path, _ = saved
    f = TreeFile(path)
    _, arrays = f.patch_record(7)
    np.testing.assert_array_equal(arrays["index"], np.array(tree.node(7).patch.index))


def test_records_round_trip_empty_and_odd_arrays():
    """Empty arrays, odd byte counts and several dtypes survive encode (the tests' writer) →
    decode (the reader) exactly."""
    arrays = {
        "empty": np.zeros((0, 3), dtype=np.int64),
        "bytes": np.arange(5, dtype=np.uint8),
        "floats": np.linspace(0, 1, 7, dtype=np.float32).reshape(7, 1),
        "big": np.arange(6, dtype=">i4"),
    }
    buf = encode_record({"k": 1}, arrays)
    attrs, back = decode_record(memoryview(buf))
    assert attrs == {"k": 1}
    for name, a in arrays.items():
        assert back[name].shape == a.shape
        np.testing.assert_array_equal(back[name], a)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The bytes of a tiny saved tree (5 nodes, 2.6 kB), small enough to flip every byte."""
    tree = ApproximationTree.build(
        fractal_terrain(5, seed=4, relief=100.0), epsilon=0.5, max_points=9
    )
    path = tmp_path_factory.mktemp("tiny") / "tiny.atree"
    write_atree(tree, path)
    return path.read_bytes()


def test_every_byte_is_covered(tiny, tmp_path):
    """Flipping any single byte of the file (the reserved prefix bytes 20–23 included) is a
    StoreError on load, never a silent success."""
    path = tmp_path / "flip.atree"
    silent = []
    for offset in range(len(tiny)):
        bad = bytearray(tiny)
        bad[offset] ^= 0xFF
        path.write_bytes(bytes(bad))
        try:
            ApproximationTree.load(path)
        except StoreError:
            continue
        silent.append(offset)
    assert silent == []


def _as_version_1(data: bytes, reserved: int = 0) -> bytes:
    """The same tree as the previous writer (format 1) laid it out: header CRC over the JSON
    header only."""
    import struct
    import zlib

    _, _, hlen, _, _ = struct.unpack_from("<8sIIII", data, 0)
    header = data[24 : 24 + hlen]
    prefix = struct.pack("<8sIIII", b"ATREE\x00\r\n", 1, hlen, zlib.crc32(header), reserved)
    return prefix + data[24:]


def test_version_1_files_load_and_their_reserved_bytes_are_checked(saved, tmp_path):
    """Files of the previous format still load (same tree); their reserved bytes, which no
    checksum covers there, must be zero."""
    tree, _, data = saved
    path = tmp_path / "v1.atree"
    path.write_bytes(_as_version_1(data))
    old = ApproximationTree.load(path)
    np.testing.assert_array_equal(old.errors, tree.errors)
    path.write_bytes(_as_version_1(data, reserved=1 << 24))
    with pytest.raises(StoreError, match="reserved"):
        ApproximationTree.load(path)


def test_a_gap_between_records_is_refused(saved, tmp_path):
    """Bytes that no record covers (here 8 between the sections and the patches, the header
    shifted to match with its checksum recomputed) are refused: no byte escapes a checksum."""
    import json
    import struct

    _, _, data = saved
    _, _, hlen, _, _ = struct.unpack_from("<8sIIII", data, 0)
    header = json.loads(data[24 : 24 + hlen])
    base = header["patch_base"]
    header["patch_base"] += 8
    header["file_size"] += 8
    raw = json.dumps(header).encode()
    assert len(raw) <= hlen
    raw += b" " * (hlen - len(raw))
    gapped = data[:24] + raw + data[24 + hlen : base] + bytes(8) + data[base:]
    path = tmp_path / "gap.atree"
    path.write_bytes(_as_version_1(gapped))
    with pytest.raises(StoreError, match="tile"):
        ApproximationTree.load(path)
