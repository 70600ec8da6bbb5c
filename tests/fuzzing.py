"""Fuzz cases shared by tests/test_fuzz_*.py and benchmarks/fuzz_deep.py.

Reader cases: a seed file of every format (small real files of ../shared/data, or small crops
of them written in the format), mutated by byte flips, truncations, inserted bytes, header-field
overwrites with extreme values, or replaced by random bytes. The property: ``open_terrain``
returns a usable terrain (finite domain and heights) or raises an ApproxTreeError subclass;
nothing else, no hang (a watchdog ends the process) and no abort.

Builder cases: small grids (1..12 × 1..12, float32/float64) with NaN, ±inf and huge heights,
random cell size and origin, random ε, max points s, fanout d and policy. The property:
``ApproximationTree.build`` returns a tree whose errors are never NaN, whose leaves' errors are
finite and meet ε (unless the leaf is a single cell), or raises an ApproxTreeError subclass.
"""

from __future__ import annotations

import contextlib
import faulthandler
import math
import re
import shutil
import struct
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st

from approxtree.errors import ApproxTreeError

#: Seconds after which the watchdog ends a hung case (and the process, with a traceback).
WATCHDOG_SECONDS = 60.0


def fuzz_settings(cases: int, derandomize: bool = True, seconds: float = 5.0) -> settings:
    """Hypothesis settings of a fuzz run: no example database, a per-case deadline, and no
    "explain" phase (its line tracing slows numba's compiler and every reader tenfold)."""
    return settings(
        max_examples=cases,
        derandomize=derandomize,
        database=None,
        deadline=seconds * 1000.0,
        phases=[Phase.explicit, Phase.generate, Phase.shrink],
        suppress_health_check=list(HealthCheck),
    )


@contextlib.contextmanager
def watchdog(seconds: float = WATCHDOG_SECONDS) -> Iterator[None]:
    """End the process with every thread's traceback if the block runs longer than seconds.

    A hang inside native code (GDAL, lazrs, numba) cannot be interrupted from Python; exiting
    loudly is the only way to turn it into a failure instead of a stuck test run.
    """
    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


# -- seeds ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Seed:
    """A seed file: its name (extension decides the reader), bytes and reader options."""

    name: str
    data: bytes = field(repr=False)
    options: dict = field(default_factory=dict)
    # Byte offsets and struct formats of header fields worth overwriting with extreme values.
    fields: tuple[tuple[int, str], ...] = field(default=(), repr=False)


# LAS public header fields: header size, point offset, VLR count, format, record length,
# point count, scales, offsets, bounds; LAS 1.4: first EVLR, EVLR count, 64-bit point count.
_LAS_FIELDS = (
    (94, "<H"), (96, "<I"), (100, "<I"), (104, "<B"), (105, "<H"), (107, "<I"),
    (131, "<d"), (139, "<d"), (147, "<d"), (155, "<d"), (163, "<d"), (171, "<d"),
    (179, "<d"), (187, "<d"), (195, "<d"), (203, "<d"),
)  # fmt: skip
_LAS14_FIELDS = (*_LAS_FIELDS, (235, "<Q"), (243, "<I"), (247, "<Q"))
# Quantized-mesh header: centre (3 doubles), min/max height (2 floats), bounding sphere,
# horizon point, then the vertex count (u32).
_QM_FIELDS = ((0, "<d"), (8, "<d"), (16, "<d"), (24, "<f"), (28, "<f"), (88, "<I"))


def _crop(data_dir: Path, rel: str, rows: int, cols: int) -> tuple[np.ndarray, object, object]:
    """(heights (rows, cols), transform, crs) of the top-left window of a real raster."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(data_dir / rel) as ds:
        window = Window(0, 0, cols, rows)
        return ds.read(1, window=window), ds.window_transform(window), ds.crs


def _geotiff(heights: np.ndarray, transform, crs, **extra) -> bytes:
    from rasterio.io import MemoryFile

    rows, cols = heights.shape
    profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype=heights.dtype.name)
    with MemoryFile() as mem:
        with mem.open(transform=transform, crs=crs, **profile, **extra) as ds:
            ds.write(heights[np.newaxis])
        return mem.read()


def _png(pixels: np.ndarray) -> bytes:
    """A PNG of (rows, cols, 3) uint8 RGB or (rows, cols) uint16 gray pixels."""
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="PNG")
    return out.getvalue()


def _terrain_rgb(h: np.ndarray) -> np.ndarray:
    v = np.rint((h + 10000.0) * 10.0).astype(np.int64)
    return np.stack([v // 65536, (v // 256) % 256, v % 256], axis=-1).astype(np.uint8)


def _terrarium(h: np.ndarray) -> np.ndarray:
    v = h + 32768.0
    whole = np.floor(v).astype(np.int64)
    frac = np.floor((v - whole) * 256.0).astype(np.int64)
    return np.stack([whole // 256, whole % 256, frac], axis=-1).astype(np.uint8)


def _las(data_dir: Path, n: int, version: str, point_format: int, laz: bool) -> bytes:
    """n points of autzen_trim.laz written as LAS/LAZ of the given version and point format."""
    import io

    import laspy

    src = laspy.read(data_dir / "lidar/autzen_trim.laz")
    header = laspy.LasHeader(version=version, point_format=point_format)
    header.scales, header.offsets = src.header.scales, src.header.offsets
    las = laspy.LasData(header)
    las.x, las.y, las.z = src.x[:n], src.y[:n], src.z[:n]
    las.classification = src.classification[:n]
    if version == "1.4":
        las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("approxtree", 1, "fuzz", b"e" * 40)])
    out = io.BytesIO()
    las.write(out, do_compress=laz)
    return out.getvalue()


def _npy(values: np.ndarray) -> bytes:
    import io

    out = io.BytesIO()
    np.save(out, values)
    return out.getvalue()


def make_seeds(data_dir: Path) -> list[Seed]:
    """One or more small seed files of every format, from the real data of data_dir."""
    d = data_dir
    heights, transform, crs = _crop(d, "nc/elev_ned_30m.tif", 24, 20)
    lux = _crop(d, "roads/lux_elev.tif", 32, 32)[0].astype(np.float64)
    lux[lux < -1000] = 150.0
    raw = (d / "scape/crater.stm").read_bytes()
    start = raw.index(b"\n") + 1
    crater = np.frombuffer(raw, ">u2", 459 * 336, start).reshape(459, 336)[:30, :40]
    p2 = "P2\n# crop of crater\n40 30\n2478\n" + "\n".join(
        " ".join(str(int(v)) for v in row) for row in crater
    )
    p5 = b"P5\n40 30\n65535\n" + crater.astype(">u2").tobytes()
    stm = b"STM 40 30 \x04\x03\x02\x01\n" + crater.astype(">u2").tobytes()
    seeds = [
        Seed("lux.tif", (d / "roads/lux_elev.tif").read_bytes()),
        Seed("nc.tif", _geotiff(heights, transform, crs, compress="deflate", tiled=False)),
        Seed("hugo.asc", (d / "edge/hugo_site.asc").read_bytes()),
        Seed("N44W072.hgt", (d / "srtm/N44W072.hgt").read_bytes()),
        Seed("N22W160v2.3a.hgt.zip", (d / "srtm/N22W160v2.3a.hgt.zip").read_bytes()),
        Seed("helens.dem", (d / "edge/SainteHelens.dem").read_bytes()),
        Seed("rgb.png", _png(_terrain_rgb(lux)), {"encoding": "terrain-rgb"}),
        Seed("terrarium.png", _png(_terrarium(lux)), {"encoding": "terrarium"}),
        Seed("gray16.png", _png(lux.astype(np.uint16))),
        Seed("crop.npy", _npy(heights)),
        Seed("jacksboro.npz", (d / "edge/jacksboro_fault_dem.npz").read_bytes()),
        Seed("crater.stm", stm, fields=((4, "2s"), (7, "2s"))),
        Seed("crater2.pgm", p2.encode()),
        Seed("crater5.pgm", p5),
        Seed("autzen.las", _las(d, 800, "1.2", 3, laz=False), fields=_LAS_FIELDS),
        Seed("autzen.laz", _las(d, 800, "1.2", 3, laz=True), fields=_LAS_FIELDS),
        Seed("autzen14.laz", _las(d, 800, "1.4", 6, laz=True), fields=_LAS14_FIELDS),
        Seed("autzen14.las", _las(d, 800, "1.4", 6, laz=False), fields=_LAS14_FIELDS),
        Seed("9_533_383.terrain", (d / "tin/9_533_383.terrain").read_bytes(), fields=_QM_FIELDS),
    ]
    return seeds


# -- mutations --------------------------------------------------------------------------------

#: Values that break naive size arithmetic: zero, one, sign and width limits, NaN, infinities.
EXTREME_INTS = (0, 1, 2, 3, 7, 255, 256, 0x7FFF, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF,
                2**63 - 1, 2**64 - 1, 808_000_000, 46_000_000_000)  # fmt: skip
EXTREME_FLOATS = (0.0, -0.0, 1e-300, -1.0, 1e300, -1e300, math.inf, -math.inf, math.nan, 3.4e38)
EXTREME_TEXT = (b"0", b"-1", b"1", b"99999999999999999999", b"1e308", b"-1e308", b"nan", b"inf",
                b"-0", b"4294967296", b"2147483648", b"")  # fmt: skip
_NUMBER = re.compile(rb"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def _position(size: int) -> st.SearchStrategy[int]:
    """A byte position, half the time in the first 512 bytes (where headers live)."""
    return st.one_of(st.integers(0, min(size, 512)), st.integers(0, size))


def _pack(fmt: str, value) -> bytes:
    """value packed as fmt, wrapped into the field's range for integers."""
    if fmt.endswith("d"):
        return struct.pack(fmt, float(value))
    if fmt.endswith("f"):
        with np.errstate(over="ignore"):
            return struct.pack(fmt, float(np.float32(value)))
    if fmt.endswith("s"):
        return str(value).encode()[: int(fmt[:-1])].ljust(int(fmt[:-1]))
    bits = 8 * struct.calcsize(fmt)
    return struct.pack(fmt, int(value) % 2**bits)


@st.composite
def mutation(draw, seed: Seed, size: int):
    """One mutation of a file of ``size`` bytes, as a (kind, arguments) tuple."""
    kinds = ["flip", "truncate", "insert", "field", "text", "word"]
    kind = draw(st.sampled_from(kinds))
    if kind == "flip":
        return ("flip", draw(_position(size - 1)), draw(st.integers(1, 255)))
    if kind == "truncate":
        return ("truncate", draw(_position(size)))
    if kind == "insert":
        return ("insert", draw(_position(size)), draw(st.binary(min_size=1, max_size=64)))
    if kind == "field" and seed.fields:
        offset, fmt = draw(st.sampled_from(seed.fields))
        pool = EXTREME_FLOATS if fmt[-1] in "df" else EXTREME_INTS
        return ("put", offset, _pack(fmt, draw(st.sampled_from(pool))))
    if kind == "text":
        return ("number", draw(st.integers(0, 63)), draw(st.sampled_from(EXTREME_TEXT)))
    # An aligned machine word of the header overwritten with an extreme value.
    fmt = draw(st.sampled_from(["<B", "<H", "<I", "<Q", "<d", ">H", ">I", ">d"]))
    pool = EXTREME_FLOATS if fmt[-1] == "d" else EXTREME_INTS
    return ("put", draw(st.integers(0, min(size, 400))), _pack(fmt, draw(st.sampled_from(pool))))


def apply(data: bytes, steps: list[tuple]) -> bytes:
    """The bytes after the mutations, in order."""
    b = bytearray(data)
    for step in steps:
        kind = step[0]
        if kind == "flip" and b:
            pos = min(step[1], len(b) - 1)
            b[pos] ^= step[2]
        elif kind == "truncate":
            del b[step[1] :]
        elif kind == "insert":
            b[step[1] : step[1]] = step[2]
        elif kind == "put":
            pos = min(step[1], len(b))
            b[pos : pos + len(step[2])] = step[2]
        elif kind == "number":
            # The k-th number of the first 2 KB (text headers) replaced by an extreme one.
            found = list(_NUMBER.finditer(bytes(b[:2048])))
            if found:
                m = found[step[1] % len(found)]
                b[m.start() : m.end()] = step[2]
    return bytes(b)


@dataclass(frozen=True)
class ReaderCase:
    """A seed and its mutations (or random bytes): short to print, exact to replay."""

    seed: Seed
    steps: tuple[tuple, ...] = ()
    random: bytes | None = None

    @property
    def data(self) -> bytes:
        return self.random if self.random is not None else apply(self.seed.data, self.steps)


@st.composite
def reader_case(draw, seeds: list[Seed]) -> ReaderCase:
    """1..3 mutations of a seed, or random bytes under its name one time in ten."""
    seed = draw(st.sampled_from(seeds))
    if draw(st.integers(0, 9)) == 0:
        return ReaderCase(seed, random=draw(st.binary(min_size=0, max_size=4096)))
    steps = draw(st.lists(mutation(seed, len(seed.data)), min_size=1, max_size=3))
    return ReaderCase(seed, tuple(steps))


def read_case(folder: Path, case: ReaderCase, watch: bool = True) -> str:
    """Read the mutated file; the outcome's name ("ok" or the ApproxTreeError subclass).

    AssertionError when the reader returns an unusable terrain; any other exception propagates.
    watch: end the process if the read hangs (off for warm-up reads that compile kernels).
    """
    from approxtree.io import open_terrain

    seed = case.seed
    path = folder / seed.name
    path.write_bytes(case.data)
    # A world file or .aux.xml GDAL may leave beside a PNG would leak into the next case.
    for extra in folder.glob(seed.name + ".*"):
        extra.unlink()
    try:
        guard = watchdog() if watch else contextlib.nullcontext()
        with guard, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            terrain = open_terrain(path, **seed.options)
            _check_terrain(terrain)
    except ApproxTreeError as exc:
        return type(exc).__name__
    return "ok"


def _check_terrain(terrain) -> None:
    """A terrain a reader returned must be usable: finite domain and heights, some points."""
    d = terrain.domain
    assert all(math.isfinite(v) for v in d.as_tuple()), f"domain {d}"
    lo, hi = terrain.z_range
    assert math.isfinite(lo) and math.isfinite(hi) and lo <= hi, f"z range {lo}..{hi}"
    assert terrain.point_count >= 1


def copy_case(folder: Path, name: str, dest: Path) -> None:
    """Keep a failing case's file for the report."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copy(folder / name, dest / name)


# -- builder cases ----------------------------------------------------------------------------

SPECIAL_HEIGHTS = (math.nan, math.inf, -math.inf, 1e300, -1e300, 3.4e38, -3.4e38, 1e-300, 0.0)
POLICIES = ("type", "auto", "grid", "tin", "rtin", "nonregular", "bogus",
            "level:grid@0-1,tin", "semantic:tin@1,grid")  # fmt: skip


@st.composite
def builder_case(draw) -> dict:
    """A small grid (heights, transform) and build parameters, some of them out of range."""
    rows, cols = draw(st.integers(2, 12)), draw(st.integers(2, 12))
    # One grid in 16 is a single row (hypothesis favours 0, hence the 7).
    if draw(st.integers(0, 15)) == 7:
        rows = 1
    plain = st.floats(-1e4, 1e4, allow_nan=False)
    special = st.sampled_from(SPECIAL_HEIGHTS)
    pool = draw(st.sampled_from(["plain", "plain", "mixed", "mixed", "special"]))
    element = {"plain": plain, "mixed": st.one_of(plain, plain, special), "special": special}
    values = draw(st.lists(element[pool], min_size=rows * cols, max_size=rows * cols))
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    with np.errstate(over="ignore"):
        heights = np.array(values, dtype=np.float64).reshape(rows, cols).astype(dtype)
    # Extreme georeferences one time in five (they are refused; the rest should build).
    cell_size, far = st.floats(1e-3, 1e4), st.floats(-1e7, 1e7)
    cell = draw(
        st.one_of(
            cell_size, cell_size, cell_size, cell_size, st.sampled_from([1e-300, 1e300, 1e-9])
        )
    )
    origin = draw(st.one_of(far, far, far, far, st.sampled_from([1e15, -1e300, 1e300, 1e9])))
    good_epsilon = st.floats(0.0, 1e4)
    bad_epsilon = st.sampled_from([0.0, -1.0, math.nan, math.inf, 1e308])
    epsilon = draw(st.one_of(good_epsilon, good_epsilon, good_epsilon, bad_epsilon))
    return {
        "heights": heights,
        "transform": (cell, 0.0, origin, 0.0, -cell, origin + rows * cell),
        "epsilon": epsilon,
        "max_points": draw(st.one_of(st.integers(4, 200), st.integers(4, 20), st.integers(-1, 3))),
        "fanout": draw(st.sampled_from([2, 4, 2, 4, 2, 4, 3, 0])),
        "policy": draw(st.sampled_from(POLICIES)),
    }


def warm_up_builder() -> None:
    """Compile every strategy's numba kernels for float32 and float64 heights (outside the
    per-case deadline and watchdog: a first compile on a busy machine takes minutes)."""
    for dtype in (np.float32, np.float64):
        heights = np.arange(25, dtype=dtype).reshape(5, 5) % 7
        heights[1, 1] = np.nan
        for policy in POLICIES[:6]:
            case = {"heights": heights, "transform": (1.0, 0.0, 0.0, 0.0, -1.0, 5.0),
                    "epsilon": 0.5, "max_points": 9, "fanout": 4, "policy": policy}  # fmt: skip
            build_case(case, watch=False)


def build_case(case: dict, watch: bool = True) -> str:
    """Build the case's tree; "ok" or the ApproxTreeError subclass raised.

    AssertionError when the tree's errors are not finite or a leaf exceeds ε while it could
    still be split; any other exception propagates.
    """
    from affine import Affine

    from approxtree.geometry import Grid
    from approxtree.tree import ApproximationTree

    try:
        guard = watchdog() if watch else contextlib.nullcontext()
        with guard, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            grid = Grid(case["heights"], Affine(*case["transform"]))
            tree = ApproximationTree.build(
                grid,
                epsilon=case["epsilon"],
                max_points=case["max_points"],
                fanout=case["fanout"],
                policy=case["policy"],
                progress=False,
            )
    except ApproxTreeError as exc:
        return type(exc).__name__
    errors = np.asarray(tree.errors)
    leaves = np.asarray(tree.child_count) == 0
    # An inner node's patch may leave data points uncovered (error inf); it is split anyway.
    assert not np.any(np.isnan(errors)) and np.all(errors >= 0), f"errors {errors}"
    assert np.all(np.isfinite(errors[leaves])), f"leaf errors {errors[leaves]}"
    over = leaves & (errors > case["epsilon"])
    # A leaf may exceed ε only when its domain cannot be split further (one cell).
    for i in np.flatnonzero(over):
        rect = tree.node(int(i)).rect
        r0, r1, c0, c1 = grid.index_range(rect)
        assert r1 - r0 <= 1 and c1 - c0 <= 1, f"leaf {i} error {errors[i]} > ε {case['epsilon']}"
    return "ok"
