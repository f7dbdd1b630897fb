# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The output-camera rule shared by the view_renderer node and ``ibr process``."""

from __future__ import annotations

import numpy as np
import pytest

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.render import output_camera

KEYFRAME = PinholeCamera(640, 480, [[500.0, 0, 300.0], [0, 510.0, 250.0], [0, 0, 1]], d=[0.1, 0, 0, 0, 0])


def test_all_zero_is_the_keyframe_camera_without_distortion() -> None:
    cam = output_camera(0, 0, 0.0, KEYFRAME)
    assert (cam.width, cam.height) == (640, 480)
    np.testing.assert_array_equal(cam.k, KEYFRAME.k)
    assert not np.any(cam.d)


def test_each_zero_takes_the_keyframes_value_and_the_principal_point_is_centred() -> None:
    cam = output_camera(320, 0, 0.0, KEYFRAME)
    assert (cam.width, cam.height) == (320, 480)
    assert cam.hfov_deg == pytest.approx(KEYFRAME.hfov_deg)
    assert (cam.cx, cam.cy) == (159.5, 239.5)
    assert output_camera(0, 0, 90.0, KEYFRAME) == PinholeCamera.from_fov(640, 480, 90.0)
    assert output_camera(960, 540, 60.0, KEYFRAME) == PinholeCamera.from_fov(960, 540, 60.0)
