# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""MVS of one refinement job, each keyframe's photometric depth computed once per flight.

COLMAP's geometric depth of a view is its photometric depth checked against the photometric depths
of its neighbours (:func:`~ibr_ros.core.depth.mvs.geometric_filter`). Per job that is 1 + N sweeps
for one depth map (the reference and its N neighbours, each neighbour against the other views of
the job). Across a flight every keyframe is a neighbour of several others: with a
:class:`PhotometricCache` (``reuse_neighbour_depth``), :func:`job_depth` keeps the photometric depth
of each keyframe it swept and sweeps a neighbour only when the cache lacks it (about 1.6 sweeps per
keyframe over a flight instead of 5 with 4 neighbours).

A neighbour's cached depth comes from other source views than the job's: an independent check,
which on real photos keeps fewer pixels than a neighbour swept against the job's own views (so the
cache is off by default; measurements in bench/README.md).
Depths: float32 z-depth in metres, 0 = unknown; stamps: nanoseconds.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mvs import (
    MvsOptions,
    MvsResult,
    MvsView,
    geometric_filter,
    mvs_depth,
    select_neighbours,
)

__all__ = ['FLIGHT_CAPACITY', 'PhotometricCache', 'job_depth']

#: Maps a flight's cache keeps with ``reuse_neighbour_depth`` (0.9 MB each at 640x360, 3 MB at
#: 1000x750): a keyframe's neighbours are among the most recent keyframes of a sequential flight.
FLIGHT_CAPACITY = 48


class PhotometricCache:
    """Photometric MVS depth of the keyframes, by stamp; the ``capacity`` most recently used kept.

    Thread-safe (a node's refinement worker and its executor share it). ``capacity`` 0 keeps none.
    """

    def __init__(self, capacity: int = 48) -> None:
        if capacity < 0:
            raise ValueError(f'capacity must be >= 0, got {capacity}')
        self.capacity = capacity
        self._maps: OrderedDict[int, NDArray[np.float32]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @classmethod
    def for_flight(cls, reuse: bool) -> PhotometricCache:
        """The cache of a flight: :data:`FLIGHT_CAPACITY` maps with ``reuse``
        (``reuse_neighbour_depth``), else none (every job sweeps its neighbours itself)."""
        return cls(FLIGHT_CAPACITY if reuse else 0)

    def __len__(self) -> int:
        return len(self._maps)

    def get(self, stamp: int) -> NDArray[np.float32] | None:
        """The depth of keyframe ``stamp`` (read-only), or None."""
        with self._lock:
            d = self._maps.get(int(stamp))
            if d is None:
                self.misses += 1
                return None
            self._maps.move_to_end(int(stamp))
            self.hits += 1
            return d

    def put(self, stamp: int, depth: NDArray[np.float32]) -> None:
        """Keep ``depth`` (HxW float32 metres, 0 = unknown) as keyframe ``stamp``'s."""
        if self.capacity == 0:
            return
        d = np.array(depth, dtype=np.float32)
        d.setflags(write=False)
        with self._lock:
            self._maps[int(stamp)] = d
            self._maps.move_to_end(int(stamp))
            while len(self._maps) > self.capacity:
                self._maps.popitem(last=False)

    def clear(self) -> None:
        """Forget every depth (the keyframes' frame changed)."""
        with self._lock:
            self._maps.clear()


def job_depth(
    views: Sequence[MvsView],
    stamps: Sequence[int],
    depth_range: tuple[float, float],
    options: MvsOptions,
    *,
    probe_range: tuple[float, float] | None = None,
    cache: PhotometricCache | None = None,
) -> MvsResult:
    """Geometrically filtered MVS depth of ``views[0]`` with ``views[1:]`` as its source views.

    ``stamps``: the views' keyframe stamps (cache keys); ``depth_range``: (near, far) of every sweep
    (m); ``probe_range``: the range whose geometric mean is the depth at which a neighbour's own
    source views (among ``views``) are chosen, default ``depth_range``. The reference is always
    swept (its cached depth, if any, is replaced); a neighbour is swept only when ``cache`` lacks it.
    The result is the reference's :class:`~ibr_ros.core.depth.mvs.MvsResult` after
    :func:`~ibr_ros.core.depth.mvs.geometric_filter` against every neighbour; ``neighbours`` index
    ``views``.
    """
    if len(views) != len(stamps):
        raise ValueError(f'{len(views)} views but {len(stamps)} stamps')
    if len(views) < 2:
        raise ValueError('job_depth needs the reference view and at least one neighbour')
    ref, nbrs = views[0], list(views[1:])
    r = mvs_depth(
        ref.rgb, ref.camera, ref.t_wc, [v.rgb for v in nbrs], [v.camera for v in nbrs],
        np.stack([v.t_wc for v in nbrs]), depth_range=depth_range, options=options,
    )  # fmt: skip
    r = replace(r, neighbours=tuple(k + 1 for k in r.neighbours))
    if r.reason:
        return r
    if cache is not None:
        cache.put(stamps[0], r.photometric_depth)
    poses = np.stack([v.t_wc for v in views])
    cams = [v.camera for v in views]
    depths: list[NDArray[np.float32]] = [r.photometric_depth]
    for k in range(1, len(views)):
        d = cache.get(stamps[k]) if cache is not None else None
        if d is None:
            d = _photometric(k, views, poses, cams, depth_range, probe_range or depth_range, options)
            if cache is not None:
                cache.put(stamps[k], d)
        depths.append(d)
    # Checked against its kept sources and every neighbour with a depth (only the reference is filtered).
    others = [k for k in range(1, len(views)) if k in r.neighbours or depths[k].any()]
    pairs = [others] + [[] for _ in nbrs]
    filt, counts = geometric_filter(
        depths, cams, poses, pairs=pairs, min_consistent=options.min_consistent,
        max_reproj_px=options.max_reproj_px, max_rel_depth_err=options.max_rel_depth_err,
    )  # fmt: skip
    d0 = filt[0]
    conf = np.where(d0 > 0, r.confidence, 0.0).astype(np.float32)
    return replace(r, depth=d0, confidence=conf, n_consistent=counts[0])


def _photometric(
    k: int,
    views: Sequence[MvsView],
    poses: NDArray[np.float64],
    cams: list,
    depth_range: tuple[float, float],
    probe_range: tuple[float, float],
    options: MvsOptions,
) -> NDArray[np.float32]:
    """Photometric depth of ``views[k]`` from its own pick among the other ``views`` (zeros if none)."""
    v = views[k]
    src = select_neighbours(k, poses, cams, depth_range=probe_range, **options.neighbour_options())
    if not src:
        return np.zeros((v.camera.height, v.camera.width), np.float32)
    r = mvs_depth(
        v.rgb, v.camera, v.t_wc, [views[j].rgb for j in src], [cams[j] for j in src], poses[src],
        depth_range=depth_range, options=options,
    )  # fmt: skip
    return r.photometric_depth  # all zero when it failed (r.reason)
