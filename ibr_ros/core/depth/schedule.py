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

import bisect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.depth.mvs import (
    MvsOptions,
    MvsView,
    check_camera,
    depth_range_from_points,
    probe_points,
    select_neighbours,
)
from ibr_ros.core.flight.status import shard_of
from ibr_ros.core.geometry.transforms import validate_pose

__all__ = [
    'NeighbourIndex',
    'RefineJob',
    'RefineScheduler',
    'ScheduleConfig',
    'axis_scene_depth',
    'parse_depth_range',
]


def axis_scene_depth(t_wc: np.ndarray, others: Sequence[np.ndarray] | np.ndarray) -> float | None:
    """Median distance (m) along the optical axis of ``t_wc`` to its closest approach to the other axes.

    Only axes 3-90 deg apart whose closest points lie in front of both cameras count; None when
    there is none (parallel axes). ``others``: 4x4 camera-to-world poses (a sequence or an Nx4x4 array).
    """
    poses = np.asarray(others, dtype=np.float64).reshape(-1, 4, 4)
    c0, a0 = np.asarray(t_wc, dtype=np.float64)[:3, 3], np.asarray(t_wc, dtype=np.float64)[:3, 2]
    c1, a1 = poses[:, :3, 3], poses[:, :3, 2]
    b = a1 @ a0
    ok = (b >= math.cos(math.radians(90.0))) & (b <= math.cos(math.radians(3.0)))
    w = c0 - c1[ok]
    b, a1 = b[ok], a1[ok]
    d, e = w @ a0, np.einsum('ij,ij->i', a1, w)
    den = 1 - b * b
    s, u = (b * e - d) / den, (e - b * d) / den
    dists = s[(s > 0) & (u > 0)]
    return float(np.median(dists)) if dists.size else None


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
    ``reuse_neighbour_depth``: the caller keeps a filled
    :class:`~ibr_ros.core.depth.job_mvs.PhotometricCache` for the flight
    (:meth:`~ibr_ros.core.depth.job_mvs.PhotometricCache.for_flight`).
    """

    num_workers: int = 1
    worker_index: int = 0
    min_neighbours: int = 2
    refine_again: bool = False
    reuse_neighbour_depth: bool = False
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


#: Slack of :class:`NeighbourIndex`'s prefilter, so that rounding never drops a view that
#: :func:`~ibr_ros.core.depth.mvs.select_neighbours` keeps: degrees on the axis angle, pixels on the
#: image bounds, radians on the viewing cone.
_SLACK_DEG, _SLACK_PX, _SLACK_RAD = 1e-6, 1e-3, 1e-6


class NeighbourIndex:
    """Poses and intrinsics of keyframes (in the given order) as arrays, to prefilter MVS neighbours.

    :meth:`candidates` keeps a superset of the views :func:`~ibr_ros.core.depth.mvs.select_neighbours`
    can pick (so it gives the same picks on the candidates alone) with array operations over all
    views, instead of its per-view Python loop over the whole flight.
    """

    def __init__(self, views: Sequence[MvsView]) -> None:
        self.views = list(views)
        self.cameras = [v.camera for v in self.views]
        self.poses = np.array([v.t_wc for v in self.views], dtype=np.float64).reshape(-1, 4, 4)
        self.centres = self.poses[:, :3, 3]
        self.axes = self.poses[:, :3, 2]
        k = np.array([(c.fx, c.fy, c.cx, c.cy, c.width, c.height) for c in self.cameras], np.float64)
        self._k = k.reshape(-1, 6)
        fx, fy, cx, cy, w, h = self._k.T
        du = np.maximum(cx + 0.5, w - 0.5 - cx) + _SLACK_PX
        dv = np.maximum(cy + 0.5, h - 0.5 - cy) + _SLACK_PX
        #: half-angle (rad) of the cone around the optical axis that holds every pixel's ray
        self.half_angle = np.arctan(np.hypot(du / fx, dv / fy))

    def __len__(self) -> int:
        return len(self.views)

    def candidates(
        self,
        ref: int,
        probes: NDArray[np.float64],
        *,
        max_view_angle_deg: float,
        min_overlap: float,
        among: ArrayLike | None = None,
    ) -> NDArray[np.intp]:
        """Sorted positions (``ref`` excluded; only those in ``among`` when given) of the views that can
        be a source view of view ``ref`` whose scene is ``probes`` (Mx3 world points): optical axis
        within ``max_view_angle_deg`` of ``ref``'s, and ``min_overlap`` of the probes in the image.

        Rounding slack (:data:`_SLACK_DEG`, ...) errs on the side of keeping a view. Views whose
        viewing cone misses the probes' bounding ball are dropped before any projection.
        """
        idx = np.arange(len(self)) if among is None else np.unique(np.asarray(among, dtype=np.intp))
        idx = idx[idx != ref]
        a0 = self.axes[ref]
        cos = (self.axes[idx] @ a0) / np.maximum(
            np.linalg.norm(self.axes[idx], axis=1) * np.linalg.norm(a0), 1e-12
        )
        idx = idx[cos >= math.cos(math.radians(min(max_view_angle_deg + _SLACK_DEG, 180.0)))]
        m = probes.mean(axis=0)
        r = float(np.linalg.norm(probes - m, axis=1).max())
        v = m - self.centres[idx]
        d = np.linalg.norm(v, axis=1)
        with np.errstate(divide='ignore', invalid='ignore'):
            c = np.einsum('ij,ij->i', v, self.axes[idx]) / d
            reach = self.half_angle[idx] + np.arcsin(np.clip(r / d, 0.0, 1.0)) + _SLACK_RAD
        inside = d <= r * (1 + 1e-9) + 1e-9
        idx = idx[inside | (np.arccos(np.clip(c, -1.0, 1.0)) <= reach)]
        if idx.size == 0:
            return idx
        pc = np.einsum('mpk,mkl->mpl', probes[None] - self.centres[idx, None], self.poses[idx, :3, :3])
        fx, fy, cx, cy, w, h = (col[:, None] for col in self._k[idx].T)
        z = pc[..., 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            u = pc[..., 0] / z * fx + cx
            vv = pc[..., 1] / z * fy + cy
        lo = -0.5 - _SLACK_PX
        vis = (z > 0) & (u >= lo) & (u <= w - 0.5 + _SLACK_PX) & (vv >= lo) & (vv <= h - 0.5 + _SLACK_PX)
        count = vis.sum(axis=1)
        return idx[(count >= 1) & (count >= (min_overlap - 1e-9) * len(probes))]


@dataclass(eq=False)
class _Keyframe:
    stamp: int
    view: MvsView
    mine: bool
    used: tuple[int, ...] = ()  # neighbour stamps of the last successful refinement
    failed_with: int = -1  # neighbour count of the last failed attempt
    alone_warned: bool = False
    elsewhere: bool = False  # its depth was published by another worker
    checked: bool = False  # pose and camera validated
    # cached ((near, far), from_points, probe range), valid for the key (epoch, arrivals; -1: any)
    rng: tuple[tuple[float, float], bool, tuple[float, float]] | None = None
    rng_key: tuple[int, int] = (-1, -1)
    # cached neighbour stamps, chosen with probe range nbrs_rng in epoch nbrs_epoch among the first
    # nbrs_at arrivals (a later arrival only matters when it passes the prefilter)
    nbrs: tuple[int, ...] | None = None
    nbrs_rng: tuple[float, float] = (0.0, 0.0)
    nbrs_epoch: int = -1
    nbrs_at: int = 0
    probes: NDArray[np.float64] | None = None


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
        self._order: list[_Keyframe] = []  # by stamp
        self._arrivals: list[_Keyframe] = []  # in arrival order: len() is the keyframe set's version
        self._epoch = 0  # bumped when cached ranges and neighbours become invalid (set_points)
        self._index: NeighbourIndex | None = None  # of _order, rebuilt after arrivals
        self._pos: dict[int, int] = {}  # stamp -> position in _order and _index

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
        kf = _Keyframe(stamp, view, self.is_mine(stamp), elsewhere=stamp in self._elsewhere)
        self._kfs[stamp] = kf
        bisect.insort(self._order, kf, key=lambda k: k.stamp)
        self._arrivals.append(kf)
        self._index = None
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
        self._epoch += 1

    def pop_warnings(self) -> list[str]:
        """Warnings raised since the last call (each situation is reported once)."""
        out, self._warnings = self._warnings, []
        return out

    def depth_range(self, stamp_ns: int) -> tuple[float, float]:
        """MVS (near, far) in metres for the keyframe ``stamp_ns`` given the other keyframes."""
        return self._range(self._kfs[int(stamp_ns)])[0]

    def _indexed(self) -> NeighbourIndex:
        """The neighbour index of all keyframes (rebuilt after new arrivals)."""
        if self._index is None:
            self._index = NeighbourIndex([k.view for k in self._order])
            self._pos = {k.stamp: i for i, k in enumerate(self._order)}
        return self._index

    def _check_views(self) -> None:
        """Raise ValueError for a keyframe without a rigid pose or an undistorted pinhole camera
        (each keyframe checked once; :func:`select_neighbours` would refuse it)."""
        for kf in self._order:
            if kf.checked:
                continue
            validate_pose(kf.view.t_wc, field=f'keyframe {kf.stamp} ns t_wc')
            check_camera(f'keyframe {kf.stamp} ns camera', kf.view.camera)
            kf.checked = True

    def _range(self, kf: _Keyframe) -> tuple[tuple[float, float], bool, tuple[float, float]]:
        """(near, far), whether it comes from the sparse points, and the range whose geometric mean
        is the depth at which :func:`select_neighbours` probes the overlap (the scene depth, not the
        far end of a sweep that reaches beyond the horizon); cached (a range estimated from the
        other keyframes only until the next arrival)."""
        now = (self._epoch, len(self._arrivals))
        if kf.rng is not None and kf.rng_key in (now, (self._epoch, -1)):
            return kf.rng
        rng, from_points, probe, from_others = self._compute_range(kf)
        kf.rng, kf.rng_key = (rng, from_points, probe), now if from_others else (self._epoch, -1)
        return kf.rng

    def _compute_range(self, kf: _Keyframe) -> tuple[tuple[float, float], bool, tuple[float, float], bool]:
        """(near, far), whether it comes from the sparse points, the probe range (:meth:`_range`),
        whether from the other keyframes."""
        cfg = self.config
        if cfg.depth_range is not None:
            return cfg.depth_range, False, cfg.depth_range, False
        if self._points is not None:
            rng = depth_range_from_points(self._points, kf.view.camera, kf.view.t_wc, margin=POINTS_MARGIN)
            if rng is not None:
                return rng, True, rng, False
        if cfg.scene_depth_m:
            s = cfg.scene_depth_m
            return (s * cfg.near_ratio, s * cfg.far_ratio), False, self._probe(s), False
        index = self._indexed()
        i = self._pos[kf.stamp]
        # axis_scene_depth over the keyframes whose axes can converge with this one (3-90 deg
        # apart, with slack): the others are skipped by it anyway, so the median is the same.
        b = index.axes @ index.axes[i]
        near = (b >= math.cos(math.radians(90.0)) - 1e-9) & (b <= math.cos(math.radians(3.0)) + 1e-9)
        near[i] = False
        axis = axis_scene_depth(index.poses[i], index.poses[near])
        if axis is not None:
            s = axis
        else:
            c = index.centres[i]
            dist = np.linalg.norm(index.centres - c, axis=1)
            dist[i] = np.inf
            d: list[float] = []
            if len(dist) > 1:
                second = float(np.partition(dist, min(1, len(dist) - 2))[min(1, len(dist) - 2)])
                close = np.flatnonzero(dist <= second * (1 + 1e-9) + 1e-12)
                d = sorted(float(np.linalg.norm(index.poses[j][:3, 3] - c)) for j in close)[:2]
            s = 12.5 * max(float(np.mean(d)), 0.1) if d else 12.5 * 0.1
            if not self._range_warned:
                self._range_warned = True
                self._warnings.append(
                    f'optical axes do not converge: scene depth guessed as {s:.1f} m from the keyframe '
                    'spacing; set scene_depth_m or depth_range'
                )
        return (s * cfg.near_ratio, s * cfg.far_ratio), False, self._probe(s), True

    def _probe(self, scene_depth: float) -> tuple[float, float]:
        """The probe range of a scene depth (m): its geometric mean is the scene depth."""
        return scene_depth * self.config.near_ratio, scene_depth / self.config.near_ratio

    def _neighbours(self, kf: _Keyframe, rng: tuple[float, float]) -> tuple[int, ...]:
        """Stamps of :func:`select_neighbours`' picks for ``kf`` over ``rng`` among all keyframes,
        computed on the :class:`NeighbourIndex` candidates only and cached until a new keyframe
        passes the prefilter (or the range changes)."""
        index = self._indexed()
        i = self._pos[kf.stamp]
        options = self.config.mvs.neighbour_options()
        pre = {k: options[k] for k in ('max_view_angle_deg', 'min_overlap')}
        version = len(self._arrivals)
        if kf.nbrs is not None and kf.nbrs_epoch == self._epoch and kf.nbrs_rng == rng:
            if kf.nbrs_at == version:
                return kf.nbrs
            new = [self._pos[k.stamp] for k in self._arrivals[kf.nbrs_at :]]
            assert kf.probes is not None
            if not index.candidates(i, kf.probes, among=new, **pre).size:
                kf.nbrs_at = version
                return kf.nbrs
        kf.probes = probe_points(kf.view.camera, index.poses[i], math.sqrt(rng[0] * rng[1]))
        sub = np.union1d(index.candidates(i, kf.probes, **pre), [i])
        picks = select_neighbours(
            int(np.searchsorted(sub, i)), index.poses[sub], [index.cameras[j] for j in sub],
            depth_range=rng, **options,
        )  # fmt: skip
        kf.nbrs = tuple(self._order[int(sub[p])].stamp for p in picks)
        kf.nbrs_rng, kf.nbrs_epoch, kf.nbrs_at = rng, self._epoch, version
        return kf.nbrs

    def next_job(self, flush: bool = False) -> RefineJob | None:
        """The oldest keyframe of this worker due for (re)refinement, or None.

        ``flush``: no more keyframes are expected for now, refine with a single neighbour too.
        Raises ValueError from neighbour selection on a degenerate keyframe set.
        """
        if len(self._order) < 2:
            return None
        self._check_views()
        cfg = self.config
        for kf in self._order:
            if not kf.mine or kf.elsewhere or (kf.used and not cfg.refine_again):
                continue
            rng, from_points, probe = self._range(kf)
            nbrs = self._neighbours(kf, probe)
            n = len(nbrs)
            if kf.used:
                due = n > len(kf.used) and n > kf.failed_with
            else:
                due = (n >= cfg.min_neighbours or (flush and n >= 1)) and n > kf.failed_with
            if due:
                chosen = [self._kfs[s] for s in nbrs]
                return RefineJob(
                    kf.stamp,
                    kf.view,
                    nbrs,
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
