# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""SpillStore: keyframe arrays on disk during ``ibr process`` (round trip, fresh copies, cleanup)."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.jobs.process.spill import SpillStore, loaded, remapped


def test_round_trip_keeps_dtype_shape_and_values(tmp_path):
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (36, 64, 3), dtype=np.uint8)
    depth = rng.uniform(1, 90, (36, 64)).astype(np.float32)
    depth[0, :3] = (np.nan, np.inf, 0.0)
    with SpillStore(tmp_path / 'spill') as store:
        for a in (rgb, depth, np.asfortranarray(depth)):
            s = store.put(a)
            assert isinstance(s, np.memmap)
            assert s.dtype == a.dtype
            assert s.shape == a.shape
            np.testing.assert_array_equal(s, a)
            for copy in (loaded(s), remapped(s)):
                np.testing.assert_array_equal(copy, a)
            assert type(loaded(s)) is np.ndarray  # in memory, not a mapping
        assert store.nbytes == rgb.nbytes + 2 * depth.nbytes
        assert len(list((tmp_path / 'spill').iterdir())) == 3
    assert not (tmp_path / 'spill').exists()
    assert loaded(rgb) is rgb  # arrays not spilled pass through
    assert remapped(rgb) is rgb


def test_writes_to_a_mapping_never_reach_the_file(tmp_path):
    with SpillStore(tmp_path / 'spill') as store:
        s = store.put(np.zeros((4, 4), np.float32))
        s[0, 0] = 7.0  # copy-on-write
        assert loaded(s)[0, 0] == 0.0


def test_folder_removed_on_error_and_interrupt(tmp_path):
    def fail(exc: BaseException) -> None:
        with SpillStore(tmp_path / 'spill') as store:
            store.put(np.ones(3))
            raise exc

    for exc in (RuntimeError('boom'), KeyboardInterrupt()):
        with pytest.raises(type(exc)):
            fail(exc)
        assert not (tmp_path / 'spill').exists()
    SpillStore(tmp_path / 'spill')
    with pytest.raises(FileExistsError):  # a new folder each time: never another run's files
        SpillStore(tmp_path / 'spill')
