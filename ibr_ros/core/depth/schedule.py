# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Which keyframe to refine next, with which MVS neighbours and over which depth range.

Pure scheduling policy of the ``depth_refiner`` node and the offline ``ibr process`` job; it keeps
the keyframes (``MvsView``, poses are 4x4 camera-to-world matrices in metres, stamps in ns) but does
no image work itself.

* Sharding: with ``num_workers`` > 1 every worker sees all keyframes (they are everybody's
  neighbours) but refines only those whose stamp hashes to its ``worker_index`` (:func:`shard_of`,
  independent of arrival order), so each keyframe is refined exactly once.
  :meth:`RefineScheduler.reassign` changes the rule (a dead worker's keyframes go to the live ones,
  :class:`~ibr_ros.core.flight.status.ShardMembership`) and :meth:`RefineScheduler.published_elsewhere` marks
  keyframes whose depth another worker published.
* Due: a keyframe of this worker is due once :func:`~ibr_ros.core.depth.mvs.select_neighbours` finds
  ``min_neighbours`` source views among the keyframes added so far, or, with ``flush`` (the end of
  a flight), at least one; never again with the same or fewer neighbours than a failed attempt.
  With ``refine_again`` a refined keyframe is due again whenever more neighbours (up to
  ``mvs.max_neighbours``) become available (and more than in a failed attempt). The oldest due
  keyframe comes first.
* Depth range of the MVS sweep: ``depth_range`` ``(near, far)`` (m) when set; else, once the
  flight's sparse points are known (:meth:`RefineScheduler.set_points`, SfM), the range of the
  points the keyframe sees (:func:`~ibr_ros.core.depth.mvs.depth_range_from_points`, margins
  :data:`POINTS_MARGIN`), which also bounds the refined depth (:attr:`RefineJob.plausible`); else
  ``(near_ratio, far_ratio) x s`` with ``s`` the scene depth at the image centre: ``scene_depth_m``
  when set, else :func:`axis_scene_depth` (oblique and orbit flights), else (parallel axes, e.g. a
  nadir survey) 12.5 x the mean distance to the two nearest keyframes (the inverse of the
  frame_subsampler's 0.08 baseline ratio), with a warning to set ``scene_depth_m``. The sweep is
  uniform in inverse depth, so a far end far beyond the scene (``far_ratio`` 1000) costs a few
  planes and lets MVS measure ground up to the horizon; the neighbours' overlap is probed at ``s``.

Warnings are returned once each by :meth:`RefineScheduler.pop_warnings` for the caller to log.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ibr_ros.core.depth.mvs import MvsOptions, MvsView, depth_range_from_points, select_neighbours
from ibr_ros.core.flight.status import shard_of

__all__ = [
    'RefineJob',
    'RefineScheduler',
    'ScheduleConfig',
    'axis_scene_depth',
    'parse_depth_range',
]


def axis_scene_depth(t_wc: np.ndarray, others: Sequence[np.ndarray]) -> float | None:
    """Median distance (m) along the optical axis of ``t_wc`` to its closest approach to the other axes.

    Only axes 3-90 deg apart whose closest points lie in front of both cameras count; None when
    there is none (parallel axes).
    """
    c0, a0 = t_wc[:3, 3], t_wc[:3, 2]
    dists = []
    for t in others:
        c1, a1 = t[:3, 3], t[:3, 2]
        b = float(a0 @ a1)
        if not math.cos(math.radians(90.0)) <= b <= math.cos(math.radians(3.0)):
            continue
        w = c0 - c1
        d, e = float(a0 @ w), float(a1 @ w)
        s, u = (b * e - d) / (1 - b * b), (e - b * d) / (1 - b * b)
        if s > 0 and u > 0:
            dists.append(s)
    return float(np.median(dists)) if dists else None


def parse_depth_range(values: Sequence[float], name: str = 'depth_range') -> tuple[float, float] | None:
    """``[near, far]`` (m, 0 < near < far < inf) as a tuple, ``[0, 0]`` as None (automatic).

    Raises ValueError naming ``name`` and the value otherwise.
    """
    vals = [float(v) for v in values]
    if len(vals) == 2 and vals == [0.0, 0.0]:
        return None
    if len(vals) != 2 or not 0 < vals[0] < vals[1] < math.inf:
        raise ValueError(f'{name} must be [near, far] with 0 < near < far, or [0, 0]; got {list(values)}')
    return vals[0], vals[1]


@dataclass(frozen=True)
class ScheduleConfig:
    """Policy of :class:`RefineScheduler` (see the module docstring).

    ``mvs``: the MVS options the keyframes are refined with (held here only); its neighbour settings
    (:meth:`~ibr_ros.core.depth.mvs.MvsOptions.neighbour_options`) choose the neighbours.
    ``depth_range``: (near, far) in metres or None (automatic); ``scene_depth_m``: 0 = estimate.
    """

    num_workers: int = 1
    worker_index: int = 0
    min_neighbours: int = 2
    refine_again: bool = False
    depth_range: tuple[float, float] | None = None
    scene_depth_m: float = 0.0
    near_ratio: float = 0.25
    far_ratio: float = 1000.0
    mvs: MvsOptions = field(default_factory=MvsOptions)

    def __post_init__(self) -> None:
        if self.num_workers < 1:
            raise ValueError(f'num_workers must be >= 1, got {self.num_workers}')
        if not 0 <= self.worker_index < self.num_workers:
            raise ValueError(
                f'worker_index {self.worker_index} must be in [0, num_workers {self.num_workers})'
            )
        if self.min_neighbours < 1:
            raise ValueError(f'min_neighbours must be >= 1, got {self.min_neighbours}')
        if self.mvs.max_neighbours < self.min_neighbours:
            raise ValueError(
                f'max_neighbours {self.mvs.max_neighbours} must be >= min_neighbours {self.min_neighbours}'
            )
        if self.depth_range is not None:
            parse_depth_range(self.depth_range)
        if not 0 <= self.scene_depth_m < math.inf:
            raise ValueError(f'scene_depth_m must be >= 0 (0 = estimate), got {self.scene_depth_m}')
        if not 0 < self.near_ratio < self.far_ratio < math.inf:
            raise ValueError(
                f'near_ratio {self.near_ratio} and far_ratio {self.far_ratio} must satisfy 0 < near < far'
            )


#: (near, far) factors on the 1st / 99th percentile depth of the sparse points a keyframe sees: the
#: near one is generous because SfM finds few points on tree tops and roofs, the surfaces nearest a
#: nadir camera (brighton_beach: trees up to half the flight height).
POINTS_MARGIN = (0.5, 1.5)


@dataclass(frozen=True, eq=False)
class RefineJob:
    """One (re)refinement: keyframe ``stamp`` with its neighbours (stamps and views, best first).

    ``depth_range``: (near, far) of the MVS sweep in metres; ``plausible``: the same range when it
    comes from the sparse points the keyframe sees (the refined depth must lie in it), else None;
    ``seeds_w``: world points (Kx3) the keyframe observed itself in SfM (depth samples where MVS
    has none), or None; ``again``: it was refined before; ``probe_range``: the range whose geometric
    mean is the scene depth at which the neighbours' overlap was probed (None: ``depth_range``).
    """

    stamp: int
    view: MvsView
    neighbours: tuple[int, ...]
    neighbour_views: tuple[MvsView, ...]
    depth_range: tuple[float, float]
    again: bool = False
    plausible: tuple[float, float] | None = None
    seeds_w: np.ndarray | None = None
    probe_range: tuple[float, float] | None = None

    @property
    def views(self) -> list[MvsView]:
        """The reference view first, then its neighbours."""
        return [self.view, *self.neighbour_views]

    @property
    def stamps(self) -> list[int]:
        """The stamps of :attr:`views`."""
        return [self.stamp, *self.neighbours]


@dataclass(eq=False)
class _Keyframe:
    stamp: int
    view: MvsView
    mine: bool
    used: tuple[int, ...] = ()  # neighbour stamps of the last successful refinement
    failed_with: int = -1  # neighbour count of the last failed attempt
    alone_warned: bool = False
    elsewhere: bool = False  # its depth was published by another worker


class RefineScheduler:
    """Keeps the keyframes and hands out refinement jobs of this worker (see the module docstring).

    Not thread-safe: callers sharing it between threads hold one lock around every call.
    """

    def __init__(self, config: ScheduleConfig | None = None) -> None:
        self.config = config or ScheduleConfig()
        self._kfs: dict[int, _Keyframe] = {}
        self._warnings: list[str] = []
        self._range_warned = False
        self._elsewhere: set[int] = set()
        self._owns: Callable[[int], bool] = self._shard_owns
        self._points: np.ndarray | None = None
        self._observed: Mapping[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._kfs)

    def __contains__(self, stamp: object) -> bool:
        return stamp in self._kfs

    def _shard_owns(self, stamp_ns: int) -> bool:
        return shard_of(stamp_ns, self.config.num_workers) == self.config.worker_index

    def is_mine(self, stamp_ns: int) -> bool:
        """Whether this worker refines the keyframe stamped ``stamp_ns``."""
        return self._owns(int(stamp_ns))

    def reassign(self, owns: Callable[[int], bool]) -> list[int]:
        """Decide ownership with ``owns(stamp)`` from now on (e.g. a dead worker's keyframes are taken
        over); the stamps this worker gained, oldest first."""
        self._owns = owns
        gained = []
        for kf in sorted(self._kfs.values(), key=lambda k: k.stamp):
            mine = owns(kf.stamp)
            if mine and not kf.mine and not kf.used and not kf.elsewhere:
                gained.append(kf.stamp)
            kf.mine = mine
        return gained

    def published_elsewhere(self, stamp_ns: int) -> None:
        """Another worker published the depth of ``stamp_ns`` (known yet or not): never refine it here."""
        stamp = int(stamp_ns)
        self._elsewhere.add(stamp)
        if (kf := self._kfs.get(stamp)) is not None:
            kf.elsewhere = True

    def add(self, stamp_ns: int, view: MvsView) -> bool:
        """Add a keyframe; False (and nothing changes) when ``stamp_ns`` is already known."""
        stamp = int(stamp_ns)
        if stamp in self._kfs:
            return False
        self._kfs[stamp] = _Keyframe(stamp, view, self.is_mine(stamp), elsewhere=stamp in self._elsewhere)
        return True

    def view(self, stamp_ns: int) -> MvsView | None:
        """The view of keyframe ``stamp_ns``, None when unknown."""
        kf = self._kfs.get(int(stamp_ns))
        return None if kf is None else kf.view

    def refined(self) -> list[int]:
        """Stamps of this worker's keyframes refined at least once, oldest first."""
        return sorted(s for s, k in self._kfs.items() if k.mine and k.used)

    def unrefined(self) -> list[int]:
        """Stamps of this worker's keyframes not refined (yet, here or elsewhere), oldest first."""
        return sorted(s for s, k in self._kfs.items() if k.mine and not k.used and not k.elsewhere)

    def set_points(self, points_w: np.ndarray, observed: Mapping[int, np.ndarray] | None = None) -> None:
        """The flight's sparse points (Px3 world metres, the keyframe poses' frame; e.g. SfM's):
        from now on each keyframe's depth range comes from the points it sees (10 or more).
        ``observed``: by stamp, the points (Kx3) each keyframe observed itself (its jobs'
        ``seeds_w``)."""
        pts = np.asarray(points_w, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f'points_w must be Px3, got shape {pts.shape}')
        pts = pts[np.isfinite(pts).all(axis=1)]
        self._points = pts if len(pts) else None
        self._observed = dict(observed or {})

    def pop_warnings(self) -> list[str]:
        """Warnings raised since the last call (each situation is reported once)."""
        out, self._warnings = self._warnings, []
        return out

    def depth_range(self, stamp_ns: int) -> tuple[float, float]:
        """MVS (near, far) in metres for the keyframe ``stamp_ns`` given the other keyframes."""
        kf = self._kfs[int(stamp_ns)]
        return self._range(kf, [k for k in self._kfs.values() if k is not kf])[0]

    def _range(
        self, kf: _Keyframe, others: list[_Keyframe]
    ) -> tuple[tuple[float, float], bool, tuple[float, float]]:
        """(near, far), whether it comes from the sparse points, and the range whose geometric mean
        is the depth at which :func:`select_neighbours` probes the overlap (the scene depth, not the
        far end of a sweep that reaches beyond the horizon)."""
        cfg = self.config
        if cfg.depth_range is not None:
            return cfg.depth_range, False, cfg.depth_range
        if self._points is not None:
            rng = depth_range_from_points(self._points, kf.view.camera, kf.view.t_wc, margin=POINTS_MARGIN)
            if rng is not None:
                return rng, True, rng
        s = cfg.scene_depth_m or axis_scene_depth(kf.view.t_wc, [o.view.t_wc for o in others])
        if s is None:
            c = kf.view.t_wc[:3, 3]
            d = sorted(float(np.linalg.norm(o.view.t_wc[:3, 3] - c)) for o in others)[:2]
            s = 12.5 * max(float(np.mean(d)), 0.1) if d else 12.5 * 0.1
            if not self._range_warned:
                self._range_warned = True
                self._warnings.append(
                    f'optical axes do not converge: scene depth guessed as {s:.1f} m from the keyframe '
                    'spacing; set scene_depth_m or depth_range'
                )
        return (s * cfg.near_ratio, s * cfg.far_ratio), False, (s * cfg.near_ratio, s / cfg.near_ratio)

    def next_job(self, flush: bool = False) -> RefineJob | None:
        """The oldest keyframe of this worker due for (re)refinement, or None.

        ``flush``: no more keyframes are expected for now, refine with a single neighbour too.
        Raises ValueError from neighbour selection on a degenerate keyframe set.
        """
        kfs = sorted(self._kfs.values(), key=lambda k: k.stamp)
        if len(kfs) < 2:
            return None
        cfg = self.config
        poses = np.stack([k.view.t_wc for k in kfs])
        cams = [k.view.camera for k in kfs]
        options = cfg.mvs.neighbour_options()
        for i, kf in enumerate(kfs):
            if not kf.mine or kf.elsewhere or (kf.used and not cfg.refine_again):
                continue
            rng, from_points, probe = self._range(kf, kfs[:i] + kfs[i + 1 :])
            nbrs = select_neighbours(i, poses, cams, depth_range=probe, **options)
            n = len(nbrs)
            if kf.used:
                due = n > len(kf.used) and n > kf.failed_with
            else:
                due = (n >= cfg.min_neighbours or (flush and n >= 1)) and n > kf.failed_with
            if due:
                chosen = [kfs[j] for j in nbrs]
                return RefineJob(
                    kf.stamp,
                    kf.view,
                    tuple(k.stamp for k in chosen),
                    tuple(k.view for k in chosen),
                    rng,
                    again=bool(kf.used),
                    plausible=rng if from_points else None,
                    seeds_w=self._observed.get(kf.stamp),
                    probe_range=probe,
                )
            if flush and n == 0 and not kf.alone_warned:
                kf.alone_warned = True
                self._warnings.append(
                    f'keyframe {kf.stamp} ns has no neighbour with enough overlap and parallax: '
                    'not refined yet'
                )
        return None

    def done(self, job: RefineJob) -> None:
        """Record a successful refinement of ``job`` (it is due again only with more neighbours)."""
        if (kf := self._kfs.get(job.stamp)) is not None:
            kf.used = job.neighbours

    def failed(self, job: RefineJob) -> None:
        """Record a failed attempt: retried only once more neighbours than in ``job`` are found."""
        if (kf := self._kfs.get(job.stamp)) is not None:
            kf.failed_with = len(job.neighbours)
