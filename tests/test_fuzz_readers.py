"""Property-based fuzzing of the terrain readers (hypothesis; cases in tests/fuzzing.py).

Every mutated or random file either reads into a usable terrain or raises an ApproxTreeError
subclass; nothing else escapes, no case hangs (hypothesis deadline, plus a watchdog that ends
the process) and none aborts (LAS/LAZ layouts are validated before laspy/lazrs see them).
The CI profile is fixed and derandomized; benchmarks/fuzz_deep.py runs the same cases deeper.
"""

from __future__ import annotations

from collections import Counter

import pytest
from fuzzing import ReaderCase, fuzz_settings, make_seeds, read_case, reader_case
from hypothesis import given

#: Cases per CI run (about 30 ms each here).
CI_CASES = 1500


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def seeds(data_dir, folder):
    """(seed files, {name: outcome}): each seed read once unmutated.

    These first reads compile kernels and open libraries, outside any deadline or watchdog.
    """
    seeds = make_seeds(data_dir)
    outcomes = {seed.name: read_case(folder, ReaderCase(seed), watch=False) for seed in seeds}
    return seeds, outcomes


def test_seeds_read(seeds):
    """Every unmutated seed reads into a terrain (so mutations start from valid files)."""
    outcomes = seeds[1]
    assert len(outcomes) >= 19 and set(outcomes.values()) == {"ok"}, outcomes


def test_fuzz_readers(seeds, folder):
    """Mutated files of every format: a terrain or an ApproxTreeError, within the deadline."""

    @fuzz_settings(CI_CASES)
    @given(reader_case(seeds[0]))
    def case(reader_case):
        outcomes[read_case(folder, reader_case)] += 1

    outcomes: Counter[str] = Counter()
    case()
    # The mutations reach past the first checks: some files still read, most are refused.
    print(dict(outcomes))
    assert outcomes["ok"] >= CI_CASES // 20 and outcomes["TerrainFormatError"] >= CI_CASES // 4
