# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``sensor_msgs/CameraInfo`` <-> :class:`ibr_ros.core.geometry.camera.PinholeCamera`."""

from __future__ import annotations

from typing import Any

import numpy as np

from ibr_ros.core.geometry.camera import CameraError, PinholeCamera, Roi
from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, coerce_header, new_message

__all__ = ['camera_info_to_pinhole', 'pinhole_to_camera_info']


def _floats(msg: Any, name: str, size: int | None) -> np.ndarray:
    a = np.asarray(getattr(msg, name), dtype=np.float64).reshape(-1)
    if size is not None and a.size != size:
        raise MessageError(f'CameraInfo.{name} has {a.size} elements, expected {size}')
    if not np.all(np.isfinite(a)):
        raise MessageError(f'CameraInfo.{name} must be finite, got {a.tolist()}')
    return a


def camera_info_to_pinhole(msg: Any) -> PinholeCamera:
    """The :class:`PinholeCamera` of a ``sensor_msgs/CameraInfo`` of either flavour.

    An all-zero ``r`` (left unset by some drivers) is read as identity and an all-zero ``p`` as
    ``[K | 0]``. Raises MessageError naming the field for an all-zero ``k`` (uncalibrated camera),
    a zero size, non-finite values or an unsupported distortion model.
    """
    k = _floats(msg, 'k', 9)
    if not np.any(k):
        raise MessageError(f'CameraInfo.k is all zeros (uncalibrated camera): {k.tolist()}')
    w, h = int(msg.width), int(msg.height)
    if w <= 0 or h <= 0:
        raise MessageError(f'CameraInfo.width x height {w}x{h} must be positive')
    r, p = _floats(msg, 'r', 9), _floats(msg, 'p', 12)
    roi = msg.roi
    try:
        return PinholeCamera(
            width=w,
            height=h,
            k=k.reshape(3, 3),
            d=_floats(msg, 'd', None),
            distortion_model=str(msg.distortion_model),
            r=r.reshape(3, 3) if np.any(r) else np.eye(3),
            p=p.reshape(3, 4) if np.any(p) else None,
            binning_x=int(msg.binning_x),
            binning_y=int(msg.binning_y),
            roi=Roi(
                int(roi.x_offset), int(roi.y_offset), int(roi.height), int(roi.width), bool(roi.do_rectify)
            ),
        )
    except CameraError as e:
        raise MessageError(f'CameraInfo: {e}') from e


def pinhole_to_camera_info(cam: PinholeCamera, header: Any = None, *, flavor: Flavor = 'rclpy') -> Any:
    """A ``sensor_msgs/CameraInfo`` describing ``cam`` (``header`` of either flavour, default empty)."""
    header = coerce_header(header, flavor)
    roi = new_message(
        'sensor_msgs/msg/RegionOfInterest',
        flavor,
        x_offset=cam.roi.x_offset,
        y_offset=cam.roi.y_offset,
        height=cam.roi.height,
        width=cam.roi.width,
        do_rectify=cam.roi.do_rectify,
    )
    d = cam.d.copy() if flavor == 'rosbags' else cam.d.tolist()
    return new_message(
        'sensor_msgs/msg/CameraInfo',
        flavor,
        header=header,
        height=cam.height,
        width=cam.width,
        distortion_model=cam.distortion_model,
        d=d,
        k=cam.k.ravel().copy(),
        r=cam.r.ravel().copy(),
        p=cam.projection.ravel().copy(),
        binning_x=cam.binning_x,
        binning_y=cam.binning_y,
        roi=roi,
    )
