# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""TF frame names and transforms of the cameras (REP-105 world frame, REP-103 body and optical frames)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.transforms import R_BODY_FROM_OPTICAL, validate_pose

__all__ = ['T_BODY_FROM_OPTICAL', 'FrameNames', 'camera_transforms', 'keyframe_frame']

#: 4x4 transform from a REP-103 optical frame (z forward, x right, y down) to its body frame
#: (x forward, y left, z up), same origin: ``p_body = T_BODY_FROM_OPTICAL @ p_optical``.
T_BODY_FROM_OPTICAL: NDArray[np.float64] = np.eye(4)
T_BODY_FROM_OPTICAL[:3, :3] = R_BODY_FROM_OPTICAL


@dataclass(frozen=True)
class FrameNames:
    """TF frame names: ``camera``: the live camera's optical frame (the pose stream's child);
    ``body``: its REP-103 body frame between the world and the optical frame ('' = none: the world
    frame is the optical frame's parent); ``keyframe_prefix``: keyframe ``s`` (stamp in ns) is
    ``<keyframe_prefix><s>_optical_frame``. The world frame is the poses' own (``map``)."""

    camera: str = 'camera_optical_frame'
    body: str = 'camera_link'
    keyframe_prefix: str = 'keyframe_'


def keyframe_frame(prefix: str, stamp_ns: int) -> str:
    """The optical frame name of the keyframe at ``stamp_ns``."""
    return f'{prefix}{int(stamp_ns)}_optical_frame'


def camera_transforms(
    t_wc: ArrayLike, world: str, optical: str, body: str = ''
) -> list[tuple[str, str, NDArray[np.float64]]]:
    """``(parent, child, T)`` transforms placing an optical frame at pose ``t_wc`` (4x4 camera to
    ``world``) in TF: ``world -> optical`` or, with a ``body`` frame, ``world -> body`` (``t_wc``
    with the axes turned to REP-103 body axes) and the fixed ``body -> optical``. ``T`` maps child
    to parent coordinates; their product along the chain is ``t_wc``."""
    pose = validate_pose(t_wc, field='t_wc')
    if not body:
        return [(world, optical, pose)]
    t_wb = pose @ np.linalg.inv(T_BODY_FROM_OPTICAL)
    return [(world, body, t_wb), (body, optical, T_BODY_FROM_OPTICAL.copy())]
