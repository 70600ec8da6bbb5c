"""Crafted bad files: each reader answers TerrainFormatError (or warns), never aborts or hangs.

The LAS/LAZ files are autzen_trim.laz (or a LAS 1.4 copy of part of it) with header bytes
patched; the others are small files with a patched pixel size or size field. Reads that could
abort the interpreter (lazrs allocation failures), hang, or allocate hundreds of GB run in a
child process under a 4 GB address-space limit and a watchdog, so a regression fails the test
instead of killing pytest.
"""

from __future__ import annotations

import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import data_file

from approxtree import TerrainFormatError, TINPointSet
from approxtree.io import open_terrain
from approxtree.io.las_layout import check_las_layout

# Offsets in autzen_trim.laz (LAS 1.2, 6 VLRs, points at 2144, chunk table at 603,333).
AUTZEN_VLR_COUNT = 100
AUTZEN_POINT_COUNT = 107
AUTZEN_TABLE_CHUNKS = 603_333 + 4

# A child that reads the file and exits 3 on TerrainFormatError (1 on any other exception).
_CHILD = textwrap.dedent(
    """
    import resource, sys
    limit = 4 * 2**30
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    from approxtree.errors import TerrainFormatError
    from approxtree.io import open_terrain
    try:
        open_terrain(sys.argv[1])
    except TerrainFormatError as exc:
        print(exc)
        sys.exit(3)
    """
)


def _patched(src: Path, dst: Path, *patches: tuple[int, str, int]) -> Path:
    """A copy of src with struct-packed values written at byte offsets."""
    data = bytearray(src.read_bytes())
    for offset, fmt, value in patches:
        struct.pack_into(fmt, data, offset, value)
    dst.write_bytes(bytes(data))
    return dst


def _read_in_child(path: Path) -> subprocess.CompletedProcess:
    """Read a terrain file in a child process (4 GB limit, 60 s watchdog)."""
    try:
        return subprocess.run(
            [sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, timeout=60
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"reading {path.name} hangs (no answer within 60 s)")


@pytest.fixture(scope="module")
def autzen(data_dir) -> Path:
    return data_file(data_dir, "lidar/autzen_trim.laz")


@pytest.fixture(scope="module")
def layered_laz(autzen, tmp_path_factory) -> Path:
    """20,000 autzen points as LAS 1.4 point format 6: a layered LAZ (compressor 3)."""
    import laspy

    las = laspy.read(autzen)
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales, header.offsets = las.header.scales, las.header.offsets
    out = laspy.LasData(header)
    out.x, out.y, out.z = las.x[:20000], las.y[:20000], las.z[:20000]
    path = tmp_path_factory.mktemp("laz") / "f6.laz"
    out.write(path)
    return path


def _layer_sizes_offset(path: Path) -> int:
    """Byte offset of the first layer size of chunk 0: after the table offset, raw point, count."""
    data = path.read_bytes()
    point_offset, record_length = struct.unpack_from("<I", data, 96)[0], data[105]
    return point_offset + 8 + record_length + 4


@pytest.mark.parametrize(
    ("name", "patches", "word"),
    [
        # lazrs reserves 16 bytes per chunk: 2.95 G chunks → 47 GB → abort.
        ("chunks", [(AUTZEN_TABLE_CHUNKS, "<I", 0xB000_0000)], "chunks"),
        # laspy reads VLR headers until it has 808 million of them.
        ("vlrs", [(AUTZEN_VLR_COUNT, "<I", 808_000_000)], "VLRs"),
        # The chunk table offset points into the compressed points: garbage table.
        ("table", [(2144, "<q", 3000)], "chunk"),
        # laspy allocates 4.3 G points × 34 bytes: MemoryError.
        ("count", [(AUTZEN_POINT_COUNT, "<I", 0xFFFF_FFF0)], "points"),
    ],
)
def test_crafted_laz_header(autzen, tmp_path, name, patches, word):
    """A LAZ header asking for absurd memory or VLRs is refused quickly, in a child process."""
    bad = _patched(autzen, tmp_path / f"{name}.laz", *patches)
    result = _read_in_child(bad)
    assert result.returncode == 3, (result.returncode, result.stderr[-2000:])
    assert word in result.stdout and "not a valid LAS/LAZ" in result.stdout


def test_crafted_layer_size(layered_laz, tmp_path):
    """A LAS 1.4 chunk whose first layer claims 4 GB (lazrs allocates it) is refused."""
    offset = _layer_sizes_offset(layered_laz)
    bad = _patched(layered_laz, tmp_path / "layer.laz", (offset, "<I", 0xF000_0000))
    result = _read_in_child(bad)
    assert result.returncode == 3, (result.returncode, result.stderr[-2000:])
    assert "layers" in result.stdout


def test_valid_layered_and_evlr_files(layered_laz, tmp_path):
    """Valid files pass the layout checks: a layered LAZ and a LAS 1.4 with an EVLR."""
    import laspy

    cloud = open_terrain(layered_laz)
    assert isinstance(cloud, TINPointSet)
    assert cloud.point_count + cloud.duplicates_merged == 20000
    las = laspy.read(layered_laz)
    las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("approxtree", 1, "test", b"x" * 100)])
    las.write(tmp_path / "evlr.las")
    layout = check_las_layout(tmp_path / "evlr.las")
    assert (layout.point_count, layout.compressed) == (20000, False)
    assert np.array_equal(open_terrain(tmp_path / "evlr.las").points(), cloud.points())


def test_memory_bound(autzen):
    """Points that would not fit in the memory given are refused before laspy allocates them."""
    with pytest.raises(TerrainFormatError, match="GB of memory"):
        check_las_layout(autzen, memory=110_000 * 34)


# -- GeoTIFF georeference and encoded PNGs -----------------------------------------------------


@pytest.mark.parametrize("size", [float("nan"), float("inf"), -float("inf")])
def test_geotiff_unusable_pixel_size(tmp_path, size):
    """A GeoTIFF whose pixel size is NaN or infinite raises TerrainFormatError (was: ValueError)."""
    import rasterio
    from affine import Affine

    path = tmp_path / "bad.tif"
    profile = {"driver": "GTiff", "width": 4, "height": 3, "count": 1, "dtype": "float32"}
    with rasterio.open(path, "w", transform=Affine(size, 0, 0, 0, -1, 10), **profile) as ds:
        ds.write(np.arange(12, dtype=np.float32).reshape(1, 3, 4))
    with pytest.raises(TerrainFormatError, match="pixel size"):
        open_terrain(path)


def _photo(path: Path) -> Path:
    """An 8-bit RGB 'photo': uniform noise, no height encoding."""
    from PIL import Image

    pixels = np.random.default_rng(3).integers(0, 256, (20, 30, 3)).astype(np.uint8)
    Image.fromarray(pixels, "RGB").save(path)
    return path


def test_encoded_heights_warn_beyond_earth(tmp_path):
    """A photo read as Terrain-RGB/Terrarium decodes to heights no terrain has: a warning.

    Real extremes (−9,000 m, as Terrain-RGB starts at −10,000, and 8,849 m) read silently.
    """
    import warnings

    from PIL import Image

    from approxtree import TerrainDataWarning

    v = np.rint((np.array([[-9000.0, 8849.0], [0.0, 1.5]]) + 10000.0) * 10.0).astype(np.int64)
    pixels = np.stack([v // 65536, (v // 256) % 256, v % 256], axis=-1).astype(np.uint8)
    Image.fromarray(pixels, "RGB").save(tmp_path / "t.png")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grid = open_terrain(tmp_path / "t.png", encoding="terrain-rgb")
    assert grid.z_range == pytest.approx((-9000.0, 8849.0))
    photo = _photo(tmp_path / "photo.png")
    for encoding in ("terrain-rgb", "terrarium"):
        with pytest.warns(TerrainDataWarning, match="beyond any terrain on Earth"):
            grid = open_terrain(photo, encoding=encoding)
        assert grid.z_range[1] > 9000.0


def test_cli_prints_warning_line(tmp_path):
    """The CLI shows the warning as one 'Warning:' line on stderr and still answers."""
    proc = subprocess.run(
        [sys.executable, "-m", "approxtree", "info", str(_photo(tmp_path / "photo.png")),
         "--encoding", "terrain-rgb"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Warning: ") and "terrain-rgb" in lines[0]


# -- headers that claim more data than the file holds (found by tests/test_fuzz_readers.py) ----


def test_npy_header_claiming_320_gb(tmp_path):
    """An .npy whose header shape asks for 320 GB is refused before numpy allocates it."""
    path = tmp_path / "z.npy"
    np.save(path, np.zeros((24, 20), np.float32))
    data = path.read_bytes().replace(b"(24, 20)", b"(4294967296, 20)")
    # The header keeps its length (numpy pads it to 64 bytes with spaces).
    data = data.replace(b"}        ", b"}", 1)
    path.write_bytes(data)
    result = _read_in_child(path)
    assert result.returncode == 3, (result.returncode, result.stderr[-2000:])
    assert "truncated or corrupt" in result.stdout


def test_npz_member_claiming_more_than_it_holds(tmp_path):
    """A .npz entry whose header claims more bytes than the entry holds is refused."""
    import zipfile

    member = tmp_path / "elevation.npy"
    np.save(member, np.zeros((24, 20), np.float32))
    data = member.read_bytes().replace(b"(24, 20)", b"(2400000, 20000)", 1)
    data = data.replace(b"}        ", b"}", 1)
    with zipfile.ZipFile(tmp_path / "z.npz", "w") as archive:
        archive.writestr("elevation.npy", data)
    result = _read_in_child(tmp_path / "z.npz")
    assert result.returncode == 3, (result.returncode, result.stderr[-2000:])
    assert "elevation.npy" in result.stdout


def test_geotiff_claiming_60000_squared(tmp_path):
    """A compressed GeoTIFF whose size tags say 60,000 × 60,000 is refused before reading."""
    import rasterio
    from affine import Affine

    path = tmp_path / "big.tif"
    profile = dict(driver="GTiff", width=64, height=64, count=1, dtype="float32")
    tiles = dict(compress="deflate", tiled=True, blockxsize=16, blockysize=16)
    with rasterio.open(path, "w", transform=Affine(1, 0, 0, 0, -1, 64), **profile, **tiles) as ds:
        ds.write(np.zeros((1, 64, 64), np.float32))
    data = bytearray(path.read_bytes())
    ifd = struct.unpack_from("<I", data, 4)[0]
    for i in range(struct.unpack_from("<H", data, ifd)[0]):
        entry = ifd + 2 + 12 * i
        if struct.unpack_from("<H", data, entry)[0] in (256, 257):  # ImageWidth, ImageLength
            struct.pack_into("<HIHH", data, entry + 2, 3, 1, 60000, 0)
    path.write_bytes(bytes(data))
    result = _read_in_child(path)
    assert result.returncode == 3, (result.returncode, result.stderr[-2000:])
    assert "60000 × 60000" in result.stdout
