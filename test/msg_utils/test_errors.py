# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.CONVERSION_ERRORS: every way a malformed message fails to convert is one of them."""

from __future__ import annotations

import numpy as np
import pytest

import msg_utils


def _bad_messages():
    header = msg_utils.make_header(1, 'camera_optical', flavor='rosbags')
    image = msg_utils.numpy_to_image(np.zeros((4, 6, 3), np.uint8), 'rgb8', header, flavor='rosbags')
    image.step = 3  # shorter than width * 3
    info = msg_utils.new_message('sensor_msgs/msg/CameraInfo', flavor='rosbags', width=6, height=4)
    pose = msg_utils.matrix_to_pose_stamped(np.eye(4), stamp_ns=1, flavor='rosbags')
    pose.pose.orientation.w = 0.0  # a zero quaternion
    return [
        (msg_utils.image_to_rgb, image),
        (msg_utils.camera_info_to_pinhole, info),
        (msg_utils.pose_stamped_to_matrix, pose),
    ]


@pytest.mark.parametrize(('convert', 'msg'), _bad_messages())
def test_bad_messages_raise_a_conversion_error(convert, msg):
    with pytest.raises(msg_utils.CONVERSION_ERRORS):
        convert(msg)


def test_the_nodes_count_the_same_errors():
    from ibr_ros.nodes.common import BAD_MESSAGE

    assert BAD_MESSAGE is msg_utils.CONVERSION_ERRORS
