# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Policy of the live graph, as small pure classes: what the graph states decides, never a timer.

- :class:`PoseSource`: whether this flight has poses (the frame_subsampler decides it from its pose
  input, publishes it latched as :class:`FlightStatus`, and the depth_refiner follows it).
- :class:`FlightStatus`: the frame_subsampler's latched account of the flight (pose source, camera
  stream state, frame and keyframe counts), as string key-values for ``diagnostic_msgs/KeyValue``.
- :class:`ShardMembership`: which sharded refiners are alive (their heartbeats within a lease) and
  which of them owns a keyframe: a dead worker's keyframes go to the live ones.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields

__all__ = [
    'CAMERA_STATES',
    'IMAGE_TRANSPORTS',
    'POSE_MODES',
    'FlightStatus',
    'PoseSource',
    'ShardMembership',
    'shard_of',
]

#: ``pose_source`` parameter values: ``auto`` (poses iff the pose topic has a publisher when the first
#: frame is complete, or once a pose arrives), ``topic`` (always wait for poses), ``none`` (never).
POSE_MODES = ('auto', 'topic', 'none')

#: States of the camera stream: no publisher yet, publishing, every publisher gone (the end of a bag).
CAMERA_STATES = ('waiting', 'streaming', 'ended')

#: frame_subsampler ``image_transport`` -> the (relative) image topics it may subscribe, preferred first.
IMAGE_TRANSPORTS = {
    'auto': ('camera/image_raw', 'camera/image_raw/compressed'),
    'raw': ('camera/image_raw',),
    'compressed': ('camera/image_raw/compressed',),
}


class PoseSource:
    """Whether the flight has poses: ``state`` is ``'unknown'``, ``'pose'`` or ``'none'``.

    In ``auto`` the state is decided when the first frame (image + camera_info) is complete: ``pose``
    when the pose topic has a publisher then (the frame waits for its pose, however late), else
    ``none``; a pose arriving before that decides ``pose``. Decided, it holds for the flight: a pose
    arriving after ``none`` is ignored (the caller counts it), since the keyframes without poses are
    registered in an SfM frame of their own. ``topic`` is ``pose`` from the start, ``none`` is
    ``none`` and ignores poses.
    """

    def __init__(self, mode: str) -> None:
        if mode not in POSE_MODES:
            raise ValueError(f'parameter pose_source must be one of {", ".join(POSE_MODES)}, got {mode!r}')
        self.mode = mode
        self.state = {'auto': 'unknown', 'topic': 'pose', 'none': 'none'}[mode]

    def pose_arrived(self) -> bool:
        """A pose message arrived; True when that decided the state (see :attr:`ignores_poses`)."""
        if self.state != 'unknown':
            return False
        self.state = 'pose'
        return True

    @property
    def ignores_poses(self) -> bool:
        """Whether arriving poses are dropped (the flight is without poses)."""
        return self.state == 'none'

    def frame_ready(self, pose_publishers: int) -> bool:
        """A frame's image and camera_info are there without a pose; True when that decided the state."""
        if self.state != 'unknown':
            return False
        self.state = 'pose' if pose_publishers > 0 else 'none'
        return True


def shard_of(stamp_ns: int, num_workers: int) -> int:
    """The worker (0 .. ``num_workers`` - 1) that refines the keyframe stamped ``stamp_ns``."""
    digest = hashlib.blake2b(int(stamp_ns).to_bytes(8, 'little', signed=True), digest_size=8).digest()
    return int.from_bytes(digest, 'little') % num_workers


@dataclass(frozen=True)
class FlightStatus:
    """The frame_subsampler's latched status (``keyframes/status``); every field is a string value.

    ``pose_source``: ``unknown``, ``pose`` or ``none`` (:class:`PoseSource`); ``camera``: one of
    :data:`CAMERA_STATES`; ``frames``: complete frames received; ``keyframes``: keyframes published;
    ``image_topic`` / ``pose_topic``: the resolved input topics ('' while not subscribed).
    """

    pose_source: str = 'unknown'
    camera: str = 'waiting'
    frames: int = 0
    keyframes: int = 0
    image_topic: str = ''
    pose_topic: str = ''

    def to_pairs(self) -> list[tuple[str, str]]:
        return [(k, str(v)) for k, v in asdict(self).items()]

    @classmethod
    def from_pairs(cls, pairs: Iterable[tuple[str, str]]) -> FlightStatus:
        """Parse key-values (unknown keys ignored); ValueError naming a malformed field and value."""
        values: dict[str, object] = {}
        known = {f.name: f.type for f in fields(cls)}
        for key, value in pairs:
            if key not in known:
                continue
            if key in ('frames', 'keyframes'):
                try:
                    values[key] = int(value)
                except ValueError:
                    raise ValueError(f'status field {key}: {value!r} is not an integer') from None
            else:
                values[key] = value
        status = cls(**values)  # type: ignore[arg-type]  # str/int fields; their values are checked below
        if status.pose_source not in ('unknown', 'pose', 'none'):
            raise ValueError(f'status field pose_source: {status.pose_source!r} is not unknown, pose or none')
        if status.camera not in CAMERA_STATES:
            raise ValueError(
                f'status field camera: {status.camera!r} is not one of {", ".join(CAMERA_STATES)}'
            )
        return status


class ShardMembership:
    """Live refiner workers and the owner of each keyframe.

    A worker is alive while its heartbeats arrive within ``lease_s`` of each other (this worker always
    is). A worker never heard from counts as alive until ``lease_s`` after the first keyframe message
    reached this one (:meth:`data_arrived`): data arriving means discovery has matched this worker with
    the graph, so a live worker's heartbeat is due by then too (under load discovery takes seconds,
    and a lease counted from start-up would declare a live worker dead before its first heartbeat).
    A keyframe belongs to its :func:`shard_of` worker while that one is alive, else to one of the
    live workers, chosen by the same hash over their sorted indices (every worker with the same view
    of who is alive picks the same one). :meth:`synced`: every worker presumed alive has been heard from
    at least once (its heartbeat lists the keyframes whose depth it published), so this worker knows
    what is done before it refines anything. Times are seconds of one monotonic clock.
    """

    def __init__(self, num_workers: int, worker_index: int, lease_s: float) -> None:
        if not 0 <= worker_index < num_workers:
            raise ValueError(f'worker_index must be in 0..{num_workers - 1}, got {worker_index}')
        if lease_s <= 0:
            raise ValueError(f'lease_s must be > 0, got {lease_s}')
        self.num_workers = num_workers
        self.worker_index = worker_index
        self.lease_s = lease_s
        self.joined: float | None = None  # when the first keyframe message arrived
        self._seen: dict[int, float] = {}

    def data_arrived(self, now: float) -> None:
        """A keyframe message reached this worker at ``now`` (the first one starts the grace lease)."""
        if self.joined is None:
            self.joined = now

    def heard(self, worker: int, now: float) -> bool:
        """A heartbeat of ``worker`` at ``now``; True when ``worker`` was not alive before it."""
        if not 0 <= worker < self.num_workers or worker == self.worker_index:
            return False
        was = self._alive(worker, now)
        self._seen[worker] = now
        return not was

    def _alive(self, worker: int, now: float) -> bool:
        if worker == self.worker_index:
            return True
        seen = self._seen.get(worker)
        if seen is None:
            return self.joined is None or now - self.joined < self.lease_s
        return now - seen < self.lease_s

    def synced(self, now: float) -> bool:
        """Whether every other live worker has been heard from (a worker never heard counts as live
        until the grace lease after the first keyframe message has passed)."""
        return all(w in self._seen for w in self.live(now) if w != self.worker_index)

    def live(self, now: float) -> tuple[int, ...]:
        """Indices of the live workers, sorted."""
        return tuple(w for w in range(self.num_workers) if self._alive(w, now))

    def owner(self, stamp_ns: int, live: tuple[int, ...]) -> int:
        """The worker that refines keyframe ``stamp_ns`` when ``live`` (from :meth:`live`) are alive."""
        base = shard_of(stamp_ns, self.num_workers)
        if base in live or not live:
            return base
        return live[shard_of(stamp_ns, len(live))]
