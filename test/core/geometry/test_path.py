# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Query paths between keyframes."""

from __future__ import annotations

import numpy as np

from ibr_ros.core.geometry.path import interpolate_path, path_stamps
from ibr_ros.core.geometry.transforms import look_at


def test_interpolate_path_midpoints():
    a = look_at([0, 0, 50], [10, 0, 0])
    b = look_at([10, 0, 50], [20, 0, 0])
    (mid,) = interpolate_path([a, b], 5)
    assert np.allclose(mid[:3, 3], [5, 0, 50])
    assert np.allclose(mid[:3, :3] @ mid[:3, :3].T, np.eye(3))
    assert interpolate_path([a], 3) == []


def test_path_stamps_are_the_midpoints_of_the_same_pairs():
    stamps = [0, 10, 20, 30, 40]
    assert path_stamps(stamps, 2) == [5, 35]
    assert len(path_stamps(stamps, 9)) == len(interpolate_path([np.eye(4)] * 5, 9)) == 4
