# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""What the caller of ``ibr process`` chooses besides the node parameters, and its progress callback."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

#: ``progress(stage, done, total)``, in this order; stages ``frames``, ``reread`` (target_keyframes: the
#: second pass), ``sfm``, ``keyframes`` (refined), ``model`` (the renderer's keyframes prepared),
#: ``views`` (rendered), ``write`` (keyframes and views in the output bag), ``previews``.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ProcessOptions:
    """What ``ibr process`` does besides the node parameters.

    ``image_topic``/``info_topic``/``pose_topic``/``navsat_topic``: None = detect by type.
    ``sfm``: SfM mode even for a bag with poses (they are ignored: keyframes and poses as for a bag
    without). ``gps``: use the bag's NavSatFix positions in SfM mode (its fixes are passed through to
    the output bag's ``/gps/fix`` either way). ``params``: ROS 2 params
    file overriding ``config/<node>.yaml``. ``views``: novel views along the keyframe path.
    ``width``/``height``/``hfov_deg``: output intrinsics of the novel views (None = the
    view_renderer's parameters; those 0 = the last keyframe's). ``max_keyframes``: stop reading
    the bag after this many keyframes (with a target: keep the first this many of the chosen ones).
    ``target_keyframes``: about this many keyframes over the whole flight (None = the
    frame_subsampler's parameter; 0 = off). ``threads``: numba/OpenCV threads (None = all cores).
    ``overwrite``: replace an existing ``OUT/bag``.
    """

    image_topic: str | None = None
    info_topic: str | None = None
    pose_topic: str | None = None
    navsat_topic: str | None = None
    sfm: bool = False
    gps: bool = True
    params: Path | None = None
    views: int = 16
    width: int | None = None
    height: int | None = None
    hfov_deg: float | None = None
    max_keyframes: int | None = None
    target_keyframes: int | None = None
    threads: int | None = None
    overwrite: bool = False
