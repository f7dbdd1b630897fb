# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""colour_depth: one turbo colouring of inverse depth for previews (node debug topics, evaluation PNGs)."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.depth.colour import colour_depth


def test_unknown_is_black_and_near_is_warm():
    d = np.array([[np.nan, 0.0, -1.0, np.inf], [1.0, 2.0, 50.0, 100.0]], np.float32)
    rgb = colour_depth(d)
    assert rgb.dtype == np.uint8
    assert rgb.shape == (2, 4, 3)
    assert not rgb[0].any()
    near, far = rgb[1, 0].astype(int), rgb[1, 3].astype(int)
    assert near[0] > near[2]
    assert far[2] > far[0]
    np.testing.assert_array_equal(colour_depth(d, bgr=True), rgb[..., ::-1])
    assert not colour_depth(np.zeros((3, 3))).any()


def test_limits_fix_the_scale_and_clip():
    d = np.array([[1.0, 5.0, 10.0, 20.0]])
    a, b = colour_depth(d, (5.0, 10.0)), colour_depth(d[:, 1:3], (5.0, 10.0))
    np.testing.assert_array_equal(a[:, 1:3], b)  # the same depth, the same colour
    np.testing.assert_array_equal(a[0, 0], a[0, 1])  # nearer than near: clipped
    np.testing.assert_array_equal(a[0, 3], a[0, 2])  # farther than far: clipped


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match=r'depth must be HxW, got shape \(2, 2, 3\)'):
        colour_depth(np.ones((2, 2, 3)))
    with pytest.raises(ValueError, match=r'limits must be \(near, far\)'):
        colour_depth(np.ones((2, 2)), (0.0, 1.0))
