"""TexturePyramid: the baked texture and its successive halvings, as memory-mapped GeoTIFFs.

Level 0 is the full-resolution texture; level k+1 halves level k (2 × 2 box filter weighted
by alpha, so transparent texels do not darken their neighbours) until a level fits the
renderer's maximum texture size. Every level is an uncompressed, pixel-interleaved RGBA GeoTIFF
covering the domain of level 0 (odd sizes add at most one texel at the east and south edges),
opened through ``numpy.memmap``: reading a texture patch touches only its rows, so pyramids
larger than memory work. ``pyramid.json`` lists the levels.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from affine import Affine

from approxtree.errors import InvalidParameterError, StoreError
from approxtree.io.atomic import atomic_write
from approxtree.textures.base import TextureData

#: Rows handled at once while halving a level, bounding memory for huge textures.
_CHUNK_ROWS = 2048


@dataclass(frozen=True)
class PyramidLevel:
    """One level: its file, size in texels and affine georeference."""

    path: Path
    width: int
    height: int
    transform: Affine

    @property
    def texel_size(self) -> tuple[float, float]:
        return (abs(self.transform.a), abs(self.transform.e))


def _write_level(path: Path, rgba: np.ndarray, transform: Affine, crs: str | None) -> None:
    """Write (rows, cols, 4) uint8 as an uncompressed pixel-interleaved GeoTIFF, atomically."""
    import rasterio

    rows, cols, _ = rgba.shape
    profile = {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": 4,
        "dtype": "uint8",
        "transform": transform,
        "crs": crs,
        "interleave": "pixel",
        "photometric": "RGB",
        "alpha": "unassociated",
        "tiled": False,
        # Streamed output writes every strip in order, all-zero strips included (GDAL
        # otherwise defers empty strips to the end of the file and breaks the memory map).
        "streamable_output": "YES",
    }
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with rasterio.open(tmp, "w", **profile) as ds:
            for r0 in range(0, rows, _CHUNK_ROWS):
                r1 = min(rows, r0 + _CHUNK_ROWS)
                window = rasterio.windows.Window(0, r0, cols, r1 - r0)
                ds.write(np.moveaxis(np.asarray(rgba[r0:r1]), -1, 0), window=window)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _halve(src: np.ndarray) -> np.ndarray:
    """2 × 2 alpha-weighted box filter of (rows, cols, 4) uint8 → (⌈rows/2⌉, ⌈cols/2⌉, 4)."""
    rows, cols, _ = src.shape
    # Odd sizes repeat their last row or column so every output texel has four inputs.
    a = np.asarray(src, dtype=np.float64)
    if rows % 2:
        a = np.concatenate([a, a[-1:]], axis=0)
    if cols % 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    quads = a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2, 4)
    alpha = quads[..., 3]
    wsum = alpha.sum(axis=(1, 3))
    rgb = (quads[..., :3] * alpha[..., None]).sum(axis=(1, 3)) / np.maximum(wsum, 1e-12)[..., None]
    out = np.empty((*wsum.shape, 4))
    out[..., :3] = np.where(wsum[..., None] > 0, rgb, 0.0)
    out[..., 3] = alpha.mean(axis=(1, 3))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _open_memmap(path: Path) -> np.ndarray:
    """Read-only (rows, cols, 4) uint8 memory map of a level written by ``_write_level``."""
    import rasterio

    with rasterio.open(path) as ds:
        rows, cols = ds.height, ds.width
        block_rows = ds.block_shapes[0][0]
        first = ds.get_tag_item("BLOCK_OFFSET_0_0", "TIFF", bidx=1)
        last_block = (rows - 1) // block_rows
        last = ds.get_tag_item(f"BLOCK_OFFSET_0_{last_block}", "TIFF", bidx=1)
        compressed = ds.compression is not None
    if first is None or last is None or compressed:
        raise StoreError(f"{path} is not an uncompressed strip GeoTIFF; rebake the pyramid.")
    first, last = int(first), int(last)
    # Strips must follow one another so that the pixels form one contiguous array.
    if last - first != last_block * block_rows * cols * 4:
        raise StoreError(f"{path} stores its strips out of order; rebake the pyramid.")
    return np.memmap(path, dtype=np.uint8, mode="r", offset=first, shape=(rows, cols, 4))


class TexturePyramid:
    """A list of levels with one domain; level 0 finest, the last fits ``max_texture_size``."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        meta_path = self.folder / "pyramid.json"
        if not meta_path.is_file():
            raise StoreError(
                f"{self.folder} holds no pyramid.json; bake a texture pyramid into it first "
                "(approxtree bake)."
            )
        try:
            meta = json.loads(meta_path.read_text())
            self.crs: str | None = meta["crs"]
            self.max_texture_size: int = int(meta["max_texture_size"])
            self.levels = [
                PyramidLevel(
                    self.folder / lv["file"],
                    int(lv["width"]),
                    int(lv["height"]),
                    Affine(*lv["transform"]),
                )
                for lv in meta["levels"]
            ]
        except (ValueError, KeyError, TypeError) as exc:
            raise StoreError(f"{meta_path} is malformed: {exc}") from exc
        self._maps: dict[int, np.ndarray] = {}

    @classmethod
    def build(
        cls,
        texture: TextureData | np.ndarray,
        folder: str | os.PathLike,
        max_texture_size: int = 4096,
        transform: Affine | None = None,
        crs: str | None = None,
    ) -> TexturePyramid:
        """Write level 0 from ``texture`` and halve it until a level fits; return the pyramid.

        texture: a TextureData, or a (rows, cols, 4) uint8 array with ``transform`` and ``crs``.
        """
        if max_texture_size < 1 or max_texture_size & (max_texture_size - 1):
            raise InvalidParameterError(
                f"max_texture_size must be a power of two, got {max_texture_size}."
            )
        if isinstance(texture, TextureData):
            rgba, transform, crs = texture.rgba(), texture.transform, texture.crs
        else:
            rgba = texture
            if transform is None:
                raise InvalidParameterError("An RGBA array needs its transform.")
        if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.dtype != np.uint8:
            raise InvalidParameterError(
                f"A texture must be (rows, cols, 4) uint8, got {rgba.shape} {rgba.dtype}."
            )
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        levels = []
        level = 0
        current = rgba
        t = transform
        while True:
            path = folder / f"level{level}.tif"
            _write_level(path, current, t, crs)
            rows, cols = current.shape[:2]
            levels.append(
                {"file": path.name, "width": cols, "height": rows, "transform": list(t)[:6]}
            )
            if max(rows, cols) <= max_texture_size:
                break
            # Texels exactly twice as large keep every level registered on level 0; an odd size
            # repeats its last texel, so a coarser level may reach one finer texel further.
            mapped = _open_memmap(path)
            current = np.concatenate(
                [_halve(mapped[r0 : r0 + _CHUNK_ROWS]) for r0 in range(0, rows, _CHUNK_ROWS)]
            )
            t = t @ Affine.scale(2.0)
            level += 1
        meta = {"crs": crs, "max_texture_size": max_texture_size, "levels": levels}
        with atomic_write(folder / "pyramid.json") as f:
            f.write(json.dumps(meta, indent=2).encode())
        return cls(folder)

    def __len__(self) -> int:
        return len(self.levels)

    def level(self, k: int) -> np.ndarray:
        """Level k as a read-only (rows, cols, 4) uint8 memory map."""
        if k not in self._maps:
            self._maps[k] = _open_memmap(self.levels[k].path)
        return self._maps[k]

    @property
    def nbytes(self) -> int:
        """Bytes of all level files."""
        return sum(lv.path.stat().st_size for lv in self.levels)
