"""Batched patch records: the records of many patches as flat arrays plus per-patch offsets.

A *record* is what ``GeometryPatch.to_record`` returns: named little-endian arrays. A *batch*
of k records maps each name to ``(flat, offsets)``: ``flat`` (total,) holds the k records'
arrays raveled one after the other, ``offsets`` (k + 1,) int64 the start of each in ``flat``
(record i is ``flat[offsets[i]:offsets[i + 1]]``). ``from_record`` accepts such flat slices.

Everything here runs in numpy over whole batches: the only per-patch Python work a caller
does is gathering each patch's arrays into a list for ``np.concatenate``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from itertools import chain

import numpy as np

#: name → (flat (total,) array, offsets (k + 1,) int64).
Batch = dict[str, tuple[np.ndarray, np.ndarray]]


def offsets_of(counts: np.ndarray) -> np.ndarray:
    """(k + 1,) int64 exclusive prefix sums of (k,) ``counts``."""
    out = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=out[1:])
    return out


def interleave(
    segments: Sequence[tuple[np.ndarray, np.ndarray]], dtype: str
) -> tuple[np.ndarray, np.ndarray]:
    """Records built of several segments each: record i = seg_0[i] ++ seg_1[i] ++ ...

    segments: (flat, counts) per segment: flat (sum(counts),) the segment's pieces of every
    record, one after the other; counts (k,) the length of record i's piece.
    Returns (flat, offsets) of the interleaved records, in ``dtype``.
    """
    counts = np.stack([np.asarray(c, dtype=np.int64) for _, c in segments])
    offsets = offsets_of(counts.sum(axis=0))
    out = np.empty(int(offsets[-1]), dtype=dtype)
    # Where record i's piece of segment j starts in ``out``: its record's start plus the
    # lengths of the earlier segments' pieces of the same record.
    before = np.cumsum(counts, axis=0) - counts
    for j, (flat, _) in enumerate(segments):
        c = counts[j]
        dst_start = offsets[:-1] + before[j]
        src_start = offsets_of(c)[:-1]
        pos = np.repeat(dst_start - src_start, c) + np.arange(int(c.sum()), dtype=np.int64)
        out[pos] = np.asarray(flat).reshape(-1)
    return out, offsets


def fixed(rows: np.ndarray, dtype: str) -> tuple[np.ndarray, np.ndarray]:
    """(flat, offsets) of k records of the same length: rows (k, w)."""
    r = np.ascontiguousarray(np.asarray(rows, dtype=dtype)).reshape(len(rows), -1)
    return r.reshape(-1), np.arange(len(r) + 1, dtype=np.int64) * r.shape[1]


def gather(
    rows: Iterable[Iterable[float]], k: int, width: int, dtype: str
) -> tuple[np.ndarray, np.ndarray]:
    """(flat, offsets) of k fixed-width records from an iterable of k rows of ``width`` numbers
    (np.fromiter over the chained rows: no intermediate tuple-of-tuples conversion)."""
    flat = np.fromiter(chain.from_iterable(rows), dtype=dtype, count=k * width)
    return flat, np.arange(k + 1, dtype=np.int64) * width


def concat_records(records: Sequence[dict[str, np.ndarray]]) -> Batch:
    """The batch of arbitrary records (every record has the same names and dtypes)."""
    if not records:
        return {}
    out: Batch = {}
    for name in records[0]:
        parts = [np.asarray(r[name]).reshape(-1) for r in records]
        counts = np.fromiter((len(p) for p in parts), dtype=np.int64, count=len(parts))
        out[name] = (np.concatenate(parts), offsets_of(counts))
    return out


def take(batch: Batch, index: np.ndarray) -> Batch:
    """The batch of records ``index`` (k',) of ``batch``, in that order (vectorized)."""
    idx = np.asarray(index, dtype=np.int64)
    out: Batch = {}
    for name, (flat, offsets) in batch.items():
        counts = np.diff(offsets)[idx]
        new = offsets_of(counts)
        pos = np.repeat(offsets[idx] - new[:-1], counts) + np.arange(int(new[-1]), dtype=np.int64)
        out[name] = (np.asarray(flat)[pos], new)
    return out


def record_at(batch: Batch, i: int) -> dict[str, np.ndarray]:
    """Record i of a batch (views into its flat arrays)."""
    return {name: flat[offsets[i] : offsets[i + 1]] for name, (flat, offsets) in batch.items()}
