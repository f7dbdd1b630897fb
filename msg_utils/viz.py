# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Messages for standard viewers (RViz, Foxglove) <-> numpy: ``sensor_msgs/PointCloud2`` (xyz + rgb),
``visualization_msgs/MarkerArray`` (camera frustums as LINE_LIST), ``geometry_msgs/PoseArray`` and
``tf2_msgs/TFMessage``.

Point clouds have the fields ``x``, ``y``, ``z`` (FLOAT32) and ``rgb`` (FLOAT32 holding the packed
little-endian ``0x00RRGGBB``, as PCL, RViz and Foxglove read it), 16 bytes a point, one row.
``tf2_msgs`` has no PyPI wheel: rclpy-flavour TF messages need a ROS install or the
``vendor/tf2_msgs`` that ``make install`` builds (:func:`tf_available`); rosbags-flavour ones always
work (for bags).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, coerce_header, new_message
from msg_utils.image import message_data, set_uint8_data
from msg_utils.pose import matrix_to_pose, matrix_to_transform_stamped

__all__ = [
    'CLOUD_FIELDS',
    'cloud_to_points',
    'frustums_to_marker_array',
    'markers_to_array',
    'matrices_to_pose_array',
    'points_to_cloud',
    'segments_to_marker',
    'tf_available',
    'transforms_to_tf',
]

#: ``(name, byte offset)`` of the cloud's FLOAT32 fields.
CLOUD_FIELDS = (('x', 0), ('y', 4), ('z', 8), ('rgb', 12))
_FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
_POINT_STEP = 16
_LINE_LIST = 5  # visualization_msgs/Marker.LINE_LIST


def tf_available() -> bool:
    """Whether rclpy-flavour ``tf2_msgs`` messages can be made (a ROS install has tf2_msgs)."""
    return importlib.util.find_spec('tf2_msgs') is not None


def points_to_cloud(xyz: ArrayLike, rgb: ArrayLike, header: Any = None, *, flavor: Flavor = 'rclpy') -> Any:
    """``sensor_msgs/PointCloud2`` of Nx3 points (metres, in ``header.frame_id``) and Nx3 uint8 colours.

    Raises MessageError for other shapes or non-finite points.
    """
    p = np.asarray(xyz, dtype=np.float32)
    c = np.asarray(rgb)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MessageError(f'points must be Nx3, got shape {p.shape}')
    if c.shape != p.shape or c.dtype != np.uint8:
        raise MessageError(f'colours must be {p.shape[0]}x3 uint8, got {c.dtype} {c.shape}')
    if not np.isfinite(p).all():
        raise MessageError('points must be finite')
    n = p.shape[0]
    buf = np.empty((n, 4), dtype='<f4')
    buf[:, :3] = p
    packed = (c[:, 0].astype('<u4') << 16) | (c[:, 1].astype('<u4') << 8) | c[:, 2].astype('<u4')
    buf[:, 3] = packed.view('<f4')
    fields = [
        new_message('sensor_msgs/msg/PointField', flavor, name=name, offset=off, datatype=_FLOAT32, count=1)
        for name, off in CLOUD_FIELDS
    ]
    msg = new_message(
        'sensor_msgs/msg/PointCloud2',
        flavor,
        header=coerce_header(header, flavor),
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=_POINT_STEP,
        row_step=_POINT_STEP * n,
        is_dense=True,
    )
    return set_uint8_data(msg, buf)


def cloud_to_points(msg: Any) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """``(Nx3 float32 xyz, Nx3 uint8 rgb)`` of a PointCloud2 with FLOAT32 ``x``, ``y``, ``z`` and a
    packed ``rgb`` (little-endian, any point step); MessageError naming the field otherwise."""
    if msg.is_bigendian:
        raise MessageError('PointCloud2.is_bigendian: big-endian clouds are not supported')
    offsets = {str(f.name): (int(f.offset), int(f.datatype)) for f in msg.fields}
    for name, _ in CLOUD_FIELDS:
        if name not in offsets or offsets[name][1] != _FLOAT32:
            raise MessageError(f'PointCloud2.fields: no FLOAT32 field {name!r} (fields {sorted(offsets)})')
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    data = message_data(msg)
    if step < 16 or data.size < step * n:
        raise MessageError(f'PointCloud2.data: {data.size} bytes for {n} points of {step} bytes')
    rows = data[: step * n].reshape(n, step)

    def column(name: str) -> NDArray[np.uint8]:
        off = offsets[name][0]
        return np.ascontiguousarray(rows[:, off : off + 4])

    xyz = np.stack([column(a).view('<f4').reshape(n) for a in 'xyz'], axis=1).astype(np.float32)
    packed = column('rgb').view('<u4').reshape(n)
    rgb = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1).astype(np.uint8)
    return xyz, rgb


def segments_to_marker(
    segments: ArrayLike,
    *,
    ns: str,
    marker_id: int,
    header: Any = None,
    color: Sequence[float] = (1.0, 1.0, 1.0, 1.0),
    width: float = 0.02,
    flavor: Flavor = 'rclpy',
) -> Any:
    """A ``LINE_LIST`` ``visualization_msgs/Marker`` (action ADD, identity pose, never expires) of
    ``(N, 2, 3)`` segments in ``header.frame_id``; ``width`` is the line width (metres), ``color``
    RGBA in [0, 1]."""
    seg = np.asarray(segments, dtype=np.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 3) or not np.isfinite(seg).all():
        raise MessageError(f'segments must be finite (N, 2, 3), got shape {seg.shape}')
    points = [
        new_message('geometry_msgs/msg/Point', flavor, x=p[0], y=p[1], z=p[2]) for p in seg.reshape(-1, 3)
    ]
    r, g, b, a = (float(v) for v in color)
    return new_message(
        'visualization_msgs/msg/Marker',
        flavor,
        header=coerce_header(header, flavor),
        ns=ns,
        id=int(marker_id),
        type=_LINE_LIST,
        action=0,
        pose=matrix_to_pose(np.eye(4), flavor=flavor),
        scale=new_message('geometry_msgs/msg/Vector3', flavor, x=float(width), y=0.0, z=0.0),
        color=new_message('std_msgs/msg/ColorRGBA', flavor, r=r, g=g, b=b, a=a),
        points=points,
    )


def frustums_to_marker_array(
    frustums: Sequence[tuple[str, int, ArrayLike, Sequence[float]]],
    header: Any = None,
    *,
    width: float = 0.02,
    flavor: Flavor = 'rclpy',
) -> Any:
    """``visualization_msgs/MarkerArray`` of ``(namespace, id, (N, 2, 3) segments, RGBA)`` frustums,
    one LINE_LIST marker each (:func:`segments_to_marker`), all with ``header``."""
    return markers_to_array(
        [
            segments_to_marker(seg, ns=ns, marker_id=i, header=header, color=rgba, width=width, flavor=flavor)
            for ns, i, seg, rgba in frustums
        ],
        flavor=flavor,
    )


def markers_to_array(markers: Sequence[Any], *, flavor: Flavor = 'rclpy') -> Any:
    """``visualization_msgs/MarkerArray`` of ``markers`` (same flavour)."""
    return new_message('visualization_msgs/msg/MarkerArray', flavor, markers=list(markers))


def matrices_to_pose_array(
    poses: Sequence[ArrayLike], header: Any = None, *, flavor: Flavor = 'rclpy'
) -> Any:
    """``geometry_msgs/PoseArray`` of 4x4 poses in ``header.frame_id``."""
    return new_message(
        'geometry_msgs/msg/PoseArray',
        flavor,
        header=coerce_header(header, flavor),
        poses=[matrix_to_pose(t, flavor=flavor) for t in poses],
    )


def transforms_to_tf(
    transforms: Sequence[tuple[int, str, str, ArrayLike]], *, flavor: Flavor = 'rclpy'
) -> Any:
    """``tf2_msgs/TFMessage`` of ``(stamp_ns, parent, child, T)`` transforms (``T``: child to parent).

    Raises MessageError for the rclpy flavour where ``tf2_msgs`` is not installed.
    """
    if flavor == 'rclpy' and not tf_available():
        raise MessageError(
            'tf2_msgs is not installed (no PyPI wheel): TF needs a ROS 2 install or tools/build_tf2_msgs.sh'
        )
    out = [
        matrix_to_transform_stamped(t, parent=parent, child=child, stamp_ns=stamp, flavor=flavor)
        for stamp, parent, child, t in transforms
    ]
    return new_message('tf2_msgs/msg/TFMessage', flavor, transforms=out)
