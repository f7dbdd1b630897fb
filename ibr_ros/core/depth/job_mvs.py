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
cache is off by default; measurements in bench/README.md). Without the cache, a neighbour's depth
only serves to confirm the reference's: with ``MvsOptions.neighbour_roi`` (the default) it is swept
only over the pixel box and the depths where the reference's photometric depth projects
(:func:`guided_roi`), and with ``MvsOptions.neighbour_sources`` against fewer views.

The neighbours of a job are swept several at once (the numba threads shared out among them).
Depths: float32 z-depth in metres, 0 = unknown; stamps: nanoseconds.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import TypeAlias, TypeVar

import numba
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.mvs import (
    MvsOptions,
    MvsResult,
    MvsView,
    geometric_filter,
    in_view_pixels,
    mvs_depth,
    select_neighbours,
)
from ibr_ros.core.geometry.camera import PinholeCamera

__all__ = [
    'FLIGHT_CAPACITY',
    'ROI_DEPTH_SLACK',
    'ROI_MARGIN_PX',
    'ROI_MIN_SUPPORT',
    'PhotometricCache',
    'Roi',
    'guided_roi',
    'job_depth',
]

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
    swept (its cached depth, if any, is replaced); a neighbour is swept only when ``cache`` lacks it
    (whole, for the cache; else over :func:`guided_roi` with ``options.neighbour_roi``), several
    at once (the costliest first).
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
    # A neighbour's map swept over the part that sees the reference serves this job only: not with a cache.
    guided = options.neighbour_roi and (cache is None or cache.capacity == 0)

    ks = range(1, len(views))
    rois = {k: guided_roi(r.photometric_depth, cams[0], poses[0], cams[k], poses[k]) for k in ks if guided}

    def neighbour(k: int) -> NDArray[np.float32]:
        d = cache.get(stamps[k]) if cache is not None else None
        if d is None:
            d = _photometric(
                k, views, poses, cams, depth_range, probe_range or depth_range, options, guided,
                rois.get(k),
            )  # fmt: skip
            if cache is not None:
                cache.put(stamps[k], d)
        return d

    # the costliest first, so that the last ones to finish are the cheap ones
    order = sorted(
        ks, key=lambda k: -_sweep_cost(cams[k], guided, rois.get(k), depth_range, r.n_planes, options)
    )
    swept = dict(zip(order, _map_shared(neighbour, order), strict=True))
    depths += [swept[k] for k in ks]
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


_T = TypeVar('_T')


def _map_shared(fn: Callable[[int], _T], items: Sequence[int]) -> list[_T]:
    """``[fn(i) for i in items]``, several at once: the caller's numba threads are shared out among
    up to as many Python threads (each item then runs kernels on fewer threads, and its Python and
    OpenCV steps overlap the others' kernels); one at a time when numba's threading layer is not
    thread-safe. Same results as one at a time."""
    total = numba.get_num_threads()
    workers = min(total, len(items))
    if workers <= 1 or _threading_layer() not in _THREADSAFE_LAYERS:
        return [fn(i) for i in items]
    per = max(1, total // workers)

    def run(i: int) -> _T:
        numba.set_num_threads(per)
        return fn(i)

    pool = ThreadPoolExecutor(workers, thread_name_prefix='mvs')
    try:
        return list(pool.map(run, items))
    finally:  # on an error or Ctrl-C: the queued ones never start, the running ones finish
        pool.shutdown(wait=True, cancel_futures=True)


#: numba threading layers whose parallel kernels several Python threads may call at once (the
#: 'workqueue' fallback, without OpenMP or TBB, aborts the process instead).
_THREADSAFE_LAYERS = ('omp', 'tbb')


def _threading_layer() -> str:
    """numba's threading layer, '' before any parallel kernel ran (it is chosen then)."""
    try:
        return str(numba.threading_layer())
    except ValueError:
        return ''


def _sweep_cost(
    cam: PinholeCamera,
    guided: bool,
    roi: Roi | None,
    depth_range: tuple[float, float],
    n_planes: int,
    o: MvsOptions,
) -> float:
    """About the work of a neighbour's sweep in pixels x hypotheses: at full resolution the
    propagation candidates, refinement and surface steps per pixel, at the sweep scale the planes
    (``n_planes``, those of ``roi``'s window), over ``roi``'s box (0 when ``guided`` without one)."""
    fine = 7 + 2 * o.refine_steps + 1 + o.surface_passes * (2 * o.surface_steps + 1)
    if roi is None:
        return 0.0 if guided else cam.width * cam.height * (fine + n_planes * o.sweep_scale**2)
    (x0, y0, x1, y1), (near, far) = roi
    share = min(1.0, (1 / near - 1 / far) / (1 / depth_range[0] - 1 / depth_range[1]))
    return (x1 - x0) * (y1 - y0) * (fine + share * n_planes * o.sweep_scale**2)


def _photometric(
    k: int,
    views: Sequence[MvsView],
    poses: NDArray[np.float64],
    cams: list[PinholeCamera],
    depth_range: tuple[float, float],
    probe_range: tuple[float, float],
    options: MvsOptions,
    guided: bool = False,
    roi: Roi | None = None,
) -> NDArray[np.float32]:
    """Photometric depth of ``views[k]`` from its own pick among the other ``views`` (zeros if none).

    With ``options.neighbour_sources`` n > 0 the sources are the reference ``views[0]`` and the
    n - 1 best others; ``guided``: only the box and the planes of ``roi`` (:func:`guided_roi` of the
    reference's photometric depth) are swept, zeros elsewhere (everywhere when ``roi`` is None).
    """
    v = views[k]
    out = np.zeros((v.camera.height, v.camera.width), np.float32)
    src = select_neighbours(k, poses, cams, depth_range=probe_range, **options.neighbour_options())
    if options.neighbour_sources > 0:
        src = ([0] + [j for j in src if j != 0])[: options.neighbour_sources]
    if not src:
        return out
    srcs = ([views[j].rgb for j in src], [cams[j] for j in src], poses[src])
    if guided and roi is None:  # nothing of the reference projects into it
        return out
    rgb, cam, window = np.asarray(v.rgb), v.camera, None
    x0 = y0 = 0
    if roi is not None:
        (x0, y0, x1, y1), window = roi
        if (x0, y0, x1, y1) != (0, 0, cam.width, cam.height):
            rgb, cam = np.ascontiguousarray(rgb[y0:y1, x0:x1]), cam.cropped(x0, y0, x1, y1)
    r = mvs_depth(rgb, cam, v.t_wc, *srcs, depth_range=depth_range, options=options, sweep_window=window)
    out[y0 : y0 + cam.height, x0 : x0 + cam.width] = r.photometric_depth  # zero when it failed
    return out


#: Pixels added around :func:`guided_roi`'s box (full resolution): the sweep's windows, the
#: propagation radius and the edge trim reach this far, so depths inside the box are not cut short.
ROI_MARGIN_PX = 24
#: Relative slack of :func:`guided_roi`'s depth window (the geometric filter allows 1 %).
ROI_DEPTH_SLACK = 0.02
#: Support of :func:`guided_roi`'s depth window: its ends are the nearest and farthest 1 % depth
#: bins into which at least this share of the reference's pixels project (about 100 pixels at
#: 1000x750). A surface (a tree top, a roof) fills its bins; the sparse photometric outliers of the
#: sweep do not, and without this support they stretch the window over the whole depth range.
ROI_MIN_SUPPORT = 1.3e-4
#: About as many reference pixels as :func:`guided_roi` projects (a lattice of them).
_ROI_SAMPLES = 50_000


#: A pixel box (x0, y0, x1, y1), end exclusive, and a (near, far) depth window in metres.
Roi: TypeAlias = tuple[tuple[int, int, int, int], tuple[float, float]]


def guided_roi(
    ref_depth: NDArray[np.float32],
    ref_cam: PinholeCamera,
    ref_pose: NDArray[np.float64],
    cam: PinholeCamera,
    pose: NDArray[np.float64],
    margin: int = ROI_MARGIN_PX,
) -> Roi | None:
    """Where the view ``cam`` at ``pose`` can confirm the reference's depth ``ref_depth`` (HxW
    metres, 0 = unknown): the pixel box ``(x0, y0, x1, y1)`` (end exclusive, even) of the known
    reference pixels that project into it, grown by ``margin`` px, and the (near, far) z-depths (m)
    they have there (the extreme ones with :data:`ROI_MIN_SUPPORT` support), widened by
    :data:`ROI_DEPTH_SLACK`. None when none projects into it.
    """
    step = max(1, math.isqrt(ref_depth.size // _ROI_SAMPLES))  # every step-th pixel of every step-th row
    sub = ref_depth[::step, ::step]
    v, u = np.nonzero(sub > 0)
    if not len(u):
        return None
    d = sub[v, u].astype(np.float64)
    pts = ref_cam.backproject(np.c_[u * step, v * step], d) @ ref_pose[:3, :3].T + ref_pose[:3, 3]
    inside, z, px = in_view_pixels(pts, cam, pose)
    if not inside.any():
        return None
    px, z = px[inside], z[inside]
    lo = np.floor(px.min(axis=0)) - margin
    hi = np.ceil(px.max(axis=0)) + margin + 1
    x0, y0 = (max(0, int(c) // 2 * 2) for c in lo)
    x1 = min(cam.width, -(-int(hi[0]) // 2) * 2)
    y1 = min(cam.height, -(-int(hi[1]) // 2) * 2)
    near, far = _supported_extremes(z, math.ceil(ROI_MIN_SUPPORT * ref_depth.size / step**2))
    return (x0, y0, x1, y1), (near * (1 - ROI_DEPTH_SLACK), far * (1 + ROI_DEPTH_SLACK))


def _supported_extremes(z: NDArray[np.float64], support: int) -> tuple[float, float]:
    """The least and largest of the depths ``z`` (> 0) within the nearest and farthest 1 % bins
    (in log depth) holding at least ``support`` of them; min and max when no bin does."""
    bins = np.floor(np.log(z / z.min()) / math.log1p(0.01)).astype(np.intp)
    full = np.flatnonzero(np.bincount(bins) >= support)
    if not full.size:
        return float(z.min()), float(z.max())
    return float(z[bins == full[0]].min()), float(z[bins == full[-1]].max())
