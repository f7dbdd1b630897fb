# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MCAP test helpers shared by the bag and CLI tests."""

from __future__ import annotations


def corrupt_chunk(data: bytes) -> bytes:
    """``data`` (an MCAP file) with the middle of its first chunk overwritten."""
    import io

    from mcap.reader import make_reader

    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[0]
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    return data[: middle - 20] + b'\xff' * 40 + data[middle + 20 :]
