# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""write_atomic: the whole new file or the old one, and no temporary file left behind."""

from __future__ import annotations

import pytest

from ibr_ros.io.atomic import write_atomic


def test_write_atomic_replaces_the_file_whole(tmp_path) -> None:
    path = tmp_path / 'out.json'
    write_atomic(path, 'old\n')
    write_atomic(path, b'\x00new')
    assert path.read_bytes() == b'\x00new'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out.json']


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path) -> None:
    path = tmp_path / 'out.txt'
    write_atomic(path, 'old')
    with pytest.raises(TypeError):
        write_atomic(path, 42)  # type: ignore[arg-type]
    assert path.read_text() == 'old'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out.txt']
