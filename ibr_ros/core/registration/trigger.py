# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""When the depth_refiner registers keyframes itself (SfM mode): pure policy, no images, no ROS.

:class:`SfmTrigger` follows what the graph states and decides; the node does the work (runs
:class:`~ibr_ros.core.registration.sfm_session.SfmSession`, publishes, logs). Its rules:

* ``'always'``: SfM mode from the start; poses on ``keyframes/pose`` are ignored (they are the
  node's own).
* ``'auto'``: SfM mode once the frame_subsampler's status says the flight has no poses, never on a
  timer (until the status comes, keyframes wait for their poses, however late), and only while no
  pose has arrived (then the flight stays posed). Keyframes that waited are registered first.
* ``'off'``: never; keyframes without poses are not refined.
* Once in SfM mode the flight stays in it (its frame is fixed), whatever a later status says.
* Registration is due when ``min_keyframes`` keyframes are there for the first one, then after
  every ``every`` new keyframes, or with at least one new keyframe when the flight is flushed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ibr_ros.core.registration.sfm_session import ScaleHint

__all__ = ['SFM_MODES', 'SfmConfig', 'SfmMode', 'SfmTrigger', 'StatusDecision']

SfmMode = Literal['auto', 'always', 'off']
#: The values of :attr:`SfmConfig.mode`.
SFM_MODES: tuple[SfmMode, ...] = ('auto', 'always', 'off')

#: What a flight status changes: ``'start'`` SfM mode starts now (register :attr:`SfmTrigger.waiting`);
#: ``'keep_poses'`` the flight has no poses but poses arrived: it stays with them; ``'keep_sfm'``
#: poses arrive now but the flight stays in SfM mode; ``''`` nothing.
StatusDecision = Literal['start', 'keep_poses', 'keep_sfm', '']


@dataclass(frozen=True)
class SfmConfig:
    """SfM mode of the depth_refiner: when (``mode``, ``min_keyframes``, ``every``; see the module
    docstring) and how (:class:`~ibr_ros.core.registration.sfm_session.SfmSession`'s ``max_side``,
    px, 0 = as received, and ``scale``: the length that makes the frame metric, None = unit-less)."""

    mode: SfmMode = 'auto'
    min_keyframes: int = 4
    every: int = 2
    max_side: int = 640
    scale: ScaleHint | None = None

    def __post_init__(self) -> None:
        if self.mode not in SFM_MODES:
            raise ValueError(f"SfmConfig.mode must be 'auto', 'always' or 'off', got {self.mode!r}")
        if self.min_keyframes < 3:
            raise ValueError(f'SfmConfig.min_keyframes must be >= 3, got {self.min_keyframes}')
        if self.every < 1:
            raise ValueError(f'SfmConfig.every must be >= 1, got {self.every}')
        if self.max_side < 0:
            raise ValueError(f'SfmConfig.max_side must be >= 0 (0 = as received), got {self.max_side}')


class SfmTrigger:
    """Whether keyframes are registered here, which wait, and when to register (module docstring).

    Not thread-safe: callers sharing it between threads hold one lock around every call.
    """

    def __init__(self, config: SfmConfig | None = None) -> None:
        self.config = config or SfmConfig()
        #: In SfM mode: keyframes without poses are registered here, ``keyframes/pose`` is ignored.
        self.active = self.config.mode == 'always'
        #: Poses used so far (a posed flight never goes to SfM mode).
        self.poses_seen = 0
        #: Stamps of keyframes that arrived without a pose before any pose was seen.
        self.waiting: set[int] = set()
        #: Stamps of keyframes queued for registration, in arrival order.
        self.queue: list[int] = []

    @property
    def mode(self) -> SfmMode:
        return self.config.mode

    def pose(self) -> bool:
        """A keyframe's pose arrived: whether to use it (in SfM mode they are the node's own)."""
        if self.active:
            return False
        self.poses_seen += 1
        return True

    def wait_for_pose(self, stamp_ns: int) -> bool:
        """Keyframe ``stamp_ns`` has its image and camera_info but no pose (outside SfM mode): it waits,
        noted while no pose was seen. True when this makes three (worth one log line)."""
        stamp = int(stamp_ns)
        if self.poses_seen or stamp in self.waiting:
            return False
        self.waiting.add(stamp)
        return len(self.waiting) == 3

    def status(self, pose_source: str) -> StatusDecision:
        """The flight status says where poses come from (``'pose'``, ``'none'``, ``'unknown'``, ...).

        ``'start'`` sets :attr:`active`; the caller then registers the :attr:`waiting` keyframes.
        """
        if pose_source == 'none' and self.mode == 'auto' and not self.active:
            if self.poses_seen:
                return 'keep_poses'
            self.active = True
            return 'start'
        if pose_source == 'pose' and self.active and self.mode == 'auto':
            return 'keep_sfm'
        return ''

    def add(self, stamp_ns: int) -> None:
        """Queue keyframe ``stamp_ns`` (no pose) for the next registration."""
        self.queue.append(int(stamp_ns))

    def due(self, flush: bool, registered: int, framed: bool) -> bool:
        """Whether to register now: ``registered`` keyframes were given to SfM before, ``framed``: a
        registration defined the frame; ``flush``: no more keyframes are expected for now."""
        added = len(self.queue)
        if not self.active or added == 0:
            return False
        if not framed:
            return registered + added >= self.config.min_keyframes
        return added >= self.config.every or flush

    def take(self) -> list[int]:
        """The queued stamps, oldest first; the queue is then empty."""
        queue, self.queue = self.queue, []
        return queue
