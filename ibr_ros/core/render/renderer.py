# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Novel-view rendering from posed RGB-D source views (Liu et al. 2020, Sec. III-B).

``NovelViewRenderer(views, config).render(t_wc, camera)``: the paper's pipeline; the defaults add
five steps (marked *added*) that :meth:`RenderConfig.as_paper` switches off. Conventions: poses are
4x4 camera-to-world matrices (metres) of REP-103 optical frames (z forward, x right, y down),
depths are z-depths in metres (REP-118: 0/NaN unknown, ``+inf`` sky), angles are degrees, image
coordinates are pixels with pixel centres at integers; all cameras are undistorted pinholes
(distortion ignored). Why the additions, and what they and the kernels cost: ``bench/README.md``
(section Renderer).

1. View selection: among the usable source views whose optical axis is within
   ``max_axis_angle_deg`` of the novel one (others face away and are ignored), the ``n_views``
   (at most 4) with the nearest camera centres. Views without depth, with an invalid pose or
   without a single warpable superpixel are skipped (``Rendered.skipped_views``).
2. Per view (cached, see below): SLIC superpixels, their statistics and a
   :class:`~ibr_ros.core.render.warp.WarpModel`. *Added* (``depth_split``): superpixels that
   straddle a depth step larger than ``depth_split`` (log depth) are split along it first
   (:func:`~ibr_ros.core.render.superpixels.split_at_depth_edges`), so that no superpixel smears a
   roof edge over the street below. Per query every superpixel is warped by the shape-preserving
   warp (:func:`~ibr_ros.core.render.warp.warp_superpixels`); superpixels whose reprojected median
   depth (or any sample) is at ``z <= near`` are dropped (the depth test of the paper), as are
   warps that flip the triangle or magnify it by more than ``max_magnification`` (linear).
3. Rasterisation (:func:`~ibr_ros.core.render.raster.raster_views`) of each warped triangle into a
   per-view superpixel-id image: every destination pixel is mapped back through the inverse of the
   triangle's affine map and accepted only if it lands (nearest pixel) on a pixel of that
   superpixel. Only destination pixels whose pre-image lies in the superpixel's bounding box and in
   its column extent over the source rows crossed are visited: they include every pixel that can
   pass the test, so the result is the same as scanning the whole triangle. Superpixels are drawn
   front to back by their reprojected median depth and a pixel keeps the first superpixel that
   claims it: a z-buffer at superpixel granularity. *Added* (``coverage_px``): the source pixel
   under the pre-image, reprojected with its own depth, must also land within ``coverage_px`` of
   the destination pixel, so that a superpixel whose affine warp overshoots a silhouette leaves
   those pixels to the surface behind it; a pixel that a view covers with no superpixel this way
   takes that view's nearest superpixel that failed only this test (noisy depth, e.g. trees, must
   not leave holes).
4. Blending (:func:`~ibr_ros.core.render.blend.blend_views`) of the (up to 4) warped images, per
   pixel, from the angle penalty of Chaurasia et al. 2011: the angle at the superpixel's 3D anchor
   (centroid at median depth) between the ray from the source centre and the ray from the novel
   centre, evaluated once per warped superpixel; *added* (``resolution_weight_deg``): plus that many
   degrees per unit of ULR's resolution term, so a view much farther from the surface than the novel
   camera ranks lower. ``blend='paper'``: the colour of the view with the smallest penalty (ties go
   to the nearer view). ``blend='ulr'`` (*added*, default): weights ``1 - p / p_max`` over the views
   covering the pixel (the worst of them gets 0; the best always takes part), as in ULR; views whose
   weight is below ``ulr_blend_min_weight`` times the best view's are left out (fewer colour
   lookups). ``blend='soft'``: weights ``exp(-((p - p_min) / soft_sigma_deg)^2)``.
   ``blend='stable'`` (*added*, for navigation): weights ``g * exp(-p / stable_sigma_deg)``, ``g`` the
   view's :func:`selection_gains` (1 inside the selection, fading to ~0 as the view's distance reaches
   that of the nearest view left out), so every view's share of a pixel is continuous in the pose:
   no pop when the nearest 4 change, no switch of the best view (``eval path`` measures it). Colours are
   bilinear lookups in the source image at the pre-image of the pixel, done only for the views that
   contribute. *Added* (``depth_tolerance``): the views covering the pixel vote on its surface:
   each view's superpixel depth gets the votes of the views within a factor ``1 + depth_tolerance``
   of it; when one depth has a strict majority, only the views on it take part (else all do). So a
   view whose depth misplaces a roof is outvoted instead of painting the street over it, and so is
   a single view that puts a distant hill too near. Sky superpixels are warped by rotation only and
   get penalty 0 (so the nearest view supplies the sky). *Added* (``depth_lookup_steps``): in
   superpixels whose affine warp misses its own reprojection samples by more than
   ``depth_lookup_min_fit_px`` (RMS, :attr:`~ibr_ros.core.render.warp.WarpResult.fit_px`), the
   affine pre-image of each pixel is corrected by Newton steps that reproject the source pixel at
   its own depth into the novel view (by at most ``depth_lookup_max_px``), so the colour comes from
   where the depth map says rather than from the affine approximation: thin trunks and fine ground
   texture stay sharp.

The kernels run in parallel (numba threads): the warp over superpixels (one region per view), the
rasterisation (all views at once) and the blend over bands of destination rows.

Caching: the per-view data (int16 labels, boxes, per-row extents, warp model; the source rgb and
depth are referenced, not copied) is computed on first use (or by :meth:`NovelViewRenderer.prepare`)
and kept in an LRU of ``max_cached_views`` views.

Distance limit: ``max_distance_m``, by default ``far_factor`` times the median scene depth of the
views (the median of each view's median finite depth): a query farther than that from every usable
view facing its direction is "far outside the capture".

Bad input: a pose that is not a 4x4 numeric matrix, or a camera that is not a ``PinholeCamera``,
raises ValueError (programming error). A 4x4 pose that is not a finite rigid transform (NaN,
zero or non-orthonormal rotation, bad last row), a camera farther than the distance limit from
every usable view, no view facing the query direction, or nothing visible give an all-invalid
:class:`Rendered` with ``reason`` set. Not thread-safe.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import overload

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import GeometryError, validate_pose
from ibr_ros.core.render.blend import BLEND_MODES, blend_views
from ibr_ros.core.render.config import RenderConfig
from ibr_ros.core.render.holes import fill_small_holes
from ibr_ros.core.render.projection import reprojection_params
from ibr_ros.core.render.raster import affine_maps, raster_views, row_spans
from ibr_ros.core.render.superpixels import slic, split_at_depth_edges, superpixel_stats
from ibr_ros.core.render.warp import WarpModel, prepare_warp, warp_superpixels

__all__ = ['NovelViewRenderer', 'Rendered', 'SourceView', 'output_camera', 'selection_gains']


def _four(arrays: list[NDArray]) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Per-view arrays of one dtype as the 4-tuple the kernels index at run time, which needs one
    numba type: all C-contiguous with the same read-only flag (as they come, e.g. all read-only
    message buffers), else C-contiguous writeable copies where needed. Views ``len(arrays)..3``
    repeat the first."""
    if not all(a.flags.c_contiguous and a.flags.writeable == arrays[0].flags.writeable for a in arrays):
        arrays = [a if a.flags.c_contiguous and a.flags.writeable else np.array(a, order='C') for a in arrays]
    same = [*arrays, *[arrays[0]] * (4 - len(arrays))]
    return same[0], same[1], same[2], same[3]


def output_camera(width: int, height: int, hfov_deg: float, keyframe: PinholeCamera) -> PinholeCamera:
    """The camera of the rendered views: ``width`` x ``height`` px with horizontal field of view
    ``hfov_deg`` (degrees) and the principal point centred; each 0 takes ``keyframe``'s (the latest
    keyframe's). All three 0: ``keyframe``'s own intrinsics, distortion dropped."""
    if not (width or height or hfov_deg):
        return PinholeCamera(keyframe.width, keyframe.height, keyframe.k)
    return PinholeCamera.from_fov(
        width or keyframe.width, height or keyframe.height, hfov_deg or keyframe.hfov_deg
    )


#: Smallest selection gain (:func:`selection_gains`): a pixel that only a fading view covers keeps its colour.
MIN_GAIN = 1e-3


def selection_gains(
    position: ArrayLike, centres: Sequence[ArrayLike], next_centre: ArrayLike | None, fade: float
) -> NDArray[np.float32]:
    """Weight factor of each selected view (``blend='stable'``), continuous in the query position.

    ``position``: the query camera centre; ``centres``: the selected views' centres; ``next_centre``:
    the nearest view left out (None: none is). With ``d`` a view's distance and ``d_next`` the left-out
    view's, ``s = (d_next - d) / (fade * d_next)`` clipped to [0, 1] and the gain is the smoothstep
    ``s^2 (3 - 2 s)`` (at least :data:`MIN_GAIN`): 1 for views well inside the selection, falling to
    ~0 as a view's distance reaches the left-out one's, where the two swap. So a view enters and leaves
    the blend with (near) zero weight instead of popping in, as Buehler et al.'s k-th-nearest threshold.
    """
    pos = np.asarray(position, np.float64)
    d = np.array([np.linalg.norm(np.asarray(c, np.float64) - pos) for c in centres])
    if next_centre is None:
        return np.ones(len(d), np.float32)
    d_next = float(np.linalg.norm(np.asarray(next_centre, np.float64) - pos))
    if not d_next > 0:
        return np.full(len(d), MIN_GAIN, np.float32)
    s = np.clip((d_next - d) / (fade * d_next), 0.0, 1.0)
    return np.maximum(s * s * (3.0 - 2.0 * s), MIN_GAIN).astype(np.float32)


@dataclass(frozen=True, eq=False)
class SourceView:
    """One posed input image.

    ``rgb``: uint8 ``(H, W, 3)``; ``depth``: float32 ``(H, W)`` z-depth in metres (0/NaN unknown,
    ``+inf`` sky) or None; ``camera``: its ``W x H`` undistorted pinhole; ``t_wc``: 4x4 camera-to-world;
    ``confidence``: float32 ``(H, W)`` depth confidence in [0, 1] or None (full confidence).
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32] | None
    camera: PinholeCamera
    t_wc: NDArray[np.float64]
    name: str = ''
    stamp: float = 0.0
    confidence: NDArray[np.float32] | None = None


@dataclass(frozen=True, eq=False)
class Rendered:
    """A rendered novel view.

    ``rgb`` uint8 ``(H, W, 3)`` (black where invalid); ``valid`` bool ``(H, W)``; ``source`` int16
    ``(H, W)`` index into the renderer's views of the view that supplied the pixel (-1 none);
    ``depth`` float32 ``(H, W)`` novel-view z-depth in metres of the supplying surface (superpixel
    median depth for ``'ibr'``; 0 invalid; sky at its Eq. 14 depth, ``+inf`` with
    ``sky_depth_factor`` 0); ``used_views`` the views selected for this
    query; ``skipped_views`` views left out as unusable (no depth, bad pose, nothing warpable);
    ``reason`` why nothing was rendered, else None.
    """

    rgb: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    source: NDArray[np.int16]
    depth: NDArray[np.float32]
    used_views: list[int] = field(default_factory=list)
    reason: str | None = None
    skipped_views: list[int] = field(default_factory=list)

    @classmethod
    def empty(cls, camera: PinholeCamera, reason: str | None, skipped: Sequence[int] = ()) -> Rendered:
        h, w = camera.height, camera.width
        return cls(
            rgb=np.zeros((h, w, 3), np.uint8),
            valid=np.zeros((h, w), np.bool_),
            source=np.full((h, w), -1, np.int16),
            depth=np.zeros((h, w), np.float32),
            reason=reason,
            skipped_views=sorted(skipped),
        )


class NearestFirst(Sequence[int]):
    """View indices ``idx`` ordered by ``dist`` (ties: in ``idx`` order, as a stable sort), sorted
    lazily: a renderer reads the first few, so only those are sorted (a partial sort of a few dozen
    nearest; the whole order only when more are read)."""

    def __init__(self, idx: NDArray[np.intp], dist: NDArray[np.float64], first: int = 32) -> None:
        self._idx, self._dist = idx, dist
        self._order: list[int] = []
        self._first = first

    def _sort(self, k: int) -> None:
        """Make the first ``k`` (at least) of the order known."""
        n = len(self._idx)
        if len(self._order) >= min(k, n):
            return
        if k < n and not self._order:
            kth = np.partition(self._dist, k - 1)[k - 1]
            sel = np.flatnonzero(self._dist <= kth)  # every tie of the k-th: the same prefix as a full sort
            if len(sel) < n:
                sel = sel[np.argsort(self._dist[sel], kind='stable')]
                self._order = [int(i) for i in self._idx[sel]]
                return
        self._order = [int(i) for i in self._idx[np.argsort(self._dist, kind='stable')]]

    def __len__(self) -> int:
        return len(self._idx)

    @overload
    def __getitem__(self, key: int) -> int: ...
    @overload
    def __getitem__(self, key: slice) -> list[int]: ...
    def __getitem__(self, key: int | slice) -> int | list[int]:
        if isinstance(key, slice):
            prefix = key.step is None and (key.start or 0) >= 0 and key.stop is not None and key.stop >= 0
            self._sort(max(key.stop, self._first) if prefix else len(self))
            return self._order[key]
        self._sort(max(key + 1, self._first) if key >= 0 else len(self))
        return self._order[key]

    def __iter__(self) -> Iterator[int]:
        for i in range(len(self)):
            if i >= len(self._order):
                self._sort(self._first if i < self._first else len(self))
            yield self._order[i]


@dataclass(frozen=True, eq=False)
class _ViewCache:
    """Per-view data: labels, boxes, per-row pixel extents (``spans[span_off[k] + y - y0]`` =
    ``(x_min, x_max)`` of superpixel ``k`` in source row ``y``) and the warp model."""

    labels: NDArray[np.integer]
    bbox: NDArray[np.int32]
    span_off: NDArray[np.int64]
    spans: NDArray[np.int16]
    model: WarpModel
    depth: NDArray[np.float32]  # as warped: +inf sky at sky_depth_factor x the largest depth
    doubt: NDArray[np.float32]  # per superpixel: 1 - mean depth confidence
    depth_copied: bool = False  # depth is not the view's own array (Eq. 14 sky, another dtype)

    @property
    def nbytes(self) -> int:
        arrays = (self.labels, self.bbox, self.span_off, self.spans, self.doubt)
        own = self.depth.nbytes if self.depth_copied else 0
        return sum(a.nbytes for a in arrays) + own + self.model.nbytes


def _doubt(
    labels: NDArray[np.integer], n_labels: int, confidence: NDArray[np.floating] | None
) -> NDArray[np.float32]:
    """Per superpixel, 1 - the mean depth confidence of its pixels (0 without a confidence)."""
    if confidence is None:
        return np.zeros(n_labels, np.float32)
    conf = np.clip(np.nan_to_num(np.asarray(confidence, np.float32)), 0.0, 1.0)
    size = np.bincount(labels.ravel(), minlength=n_labels)
    total = np.bincount(labels.ravel(), weights=conf.ravel(), minlength=n_labels)
    return (1.0 - total / np.maximum(size, 1)).astype(np.float32)


class NovelViewRenderer:
    """Render novel views from posed RGB-D source views (see the module docstring).

    Args:
        views: the source views; ``Rendered.source`` and ``used_views`` index this sequence.
        config: renderer settings.

    Raises ValueError for structurally malformed views (wrong dtype/shape, camera size mismatch).
    Views without usable depth or with an invalid pose are kept out and listed in
    ``skipped_views``. Views may be appended (:meth:`add_view`) or replaced (:meth:`replace_view`)
    later, e.g. as a keyframe model grows; indices never change.
    """

    def __init__(self, views: Sequence[SourceView], config: RenderConfig | None = None) -> None:
        self.config = config or RenderConfig()
        self.views = list(views)
        for i, v in enumerate(self.views):
            self._check_view(i, v)
        n = len(self.views)
        self._centres = np.full((n, 3), np.nan)
        self._axes = np.full((n, 3), np.nan)
        self._usable = np.zeros(n, np.bool_)
        self._view_depth = [math.nan] * n  # per view: median finite depth (NaN: none)
        self._skip_reason: dict[int, str] = {}
        self._scene_depth = math.nan
        self._cache: OrderedDict[int, _ViewCache] = OrderedDict()
        self.cache_hits = 0
        self.cache_misses = 0
        for i in range(n):
            self._admit(i)
        self._update_scene_depth()

    def _admit(self, i: int) -> None:
        """Decide whether view ``i`` is usable and record its centre, axis and median depth."""
        v = self.views[i]
        self._skip_reason.pop(i, None)
        self._cache.pop(i, None)
        self._centres[i] = self._axes[i] = np.nan
        self._usable[i] = False
        self._view_depth[i] = math.nan
        try:
            t = validate_pose(v.t_wc, field=f'views[{i}].t_wc')
        except GeometryError as e:
            self._skip_reason[i] = str(e)
            return
        if v.depth is None:
            self._skip_reason[i] = 'no depth'
            return
        sub = np.asarray(v.depth[::7, ::7], dtype=np.float32)
        known = sub[sub > 0]  # NaN compares False
        if known.size == 0:
            self._skip_reason[i] = 'depth has no known values'
            return
        finite = known[np.isfinite(known)]
        if finite.size:
            self._view_depth[i] = float(np.median(finite))
        self._centres[i] = t[:3, 3]
        self._axes[i] = t[:3, 2]
        self._usable[i] = True

    def _update_scene_depth(self) -> None:
        d = [x for x in self._view_depth if math.isfinite(x)]
        self._scene_depth = float(np.median(d)) if d else math.nan

    def add_view(self, view: SourceView) -> int:
        """Append a source view (its cache is built on first use); returns its index.

        Same checks as the constructor: ValueError for a malformed view, an unusable one is listed
        in ``skipped_views``. The scene depth (distance limit) is updated.
        """
        i = len(self.views)
        self._check_view(i, view)
        self.views.append(view)
        self._centres = np.vstack([self._centres, np.full((1, 3), np.nan)])
        self._axes = np.vstack([self._axes, np.full((1, 3), np.nan)])
        self._usable = np.append(self._usable, False)
        self._view_depth.append(math.nan)
        self._admit(i)
        self._update_scene_depth()
        return i

    def set_confidence(self, index: int, confidence: NDArray[np.float32] | None) -> None:
        """Give view ``index`` a new depth confidence (its superpixels and warp model stay cached)."""
        if not 0 <= index < len(self.views):
            raise ValueError(f'view index {index} is out of range for {len(self.views)} views')
        view = replace(self.views[index], confidence=confidence)
        self._check_view(index, view)
        self.views[index] = view
        if (c := self._cache.get(index)) is not None:
            self._cache[index] = replace(c, doubt=_doubt(c.labels, c.model.n_labels, confidence))

    def replace_view(self, index: int, view: SourceView) -> None:
        """Replace view ``index`` (e.g. with refined depth); its cached data is dropped."""
        if not 0 <= index < len(self.views):
            raise ValueError(f'view index {index} is out of range for {len(self.views)} views')
        self._check_view(index, view)
        self.views[index] = view
        self._admit(index)
        self._update_scene_depth()

    # -- views and cache ----------------------------------------------------------------------
    @staticmethod
    def _check_view(i: int, v: SourceView) -> None:
        if not isinstance(v, SourceView) or not isinstance(v.camera, PinholeCamera):
            raise ValueError(f'views[{i}] must be a SourceView with a PinholeCamera')
        h, w = v.camera.height, v.camera.width
        rgb = v.rgb
        if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8 or rgb.shape != (h, w, 3):
            raise ValueError(f'views[{i}].rgb must be uint8 ({h}, {w}, 3) like its camera')
        if v.depth is not None and (
            not isinstance(v.depth, np.ndarray)
            or v.depth.shape != (h, w)
            or not np.issubdtype(v.depth.dtype, np.floating)
        ):
            raise ValueError(f'views[{i}].depth must be None or a float ({h}, {w}) array')
        if v.confidence is not None and (
            not isinstance(v.confidence, np.ndarray) or v.confidence.shape != (h, w)
        ):
            raise ValueError(f'views[{i}].confidence must be None or a ({h}, {w}) array')

    @property
    def skipped_views(self) -> list[int]:
        """Views that cannot be used (no depth, invalid pose, nothing warpable), sorted."""
        return sorted(self._skip_reason)

    def skip_reason(self, index: int) -> str | None:
        return self._skip_reason.get(index)

    def _view_cache(self, i: int) -> _ViewCache | None:
        c = self._cache.get(i)
        if c is not None:
            self._cache.move_to_end(i)
            self.cache_hits += 1
            return c
        if not self._usable[i]:
            return None
        self.cache_misses += 1
        cfg = self.config
        v = self.views[i]
        labels = slic(v.rgb, n_segments=cfg.n_segments, compactness=cfg.compactness)
        depth = self.view_depth(i)
        if cfg.depth_split is not None:
            labels = split_at_depth_edges(
                labels, depth, log_gap=cfg.depth_split, levels=cfg.depth_split_levels,
                min_size=cfg.depth_split_min_px,
            )  # fmt: skip
        stats = superpixel_stats(
            labels, depth, min_samples=cfg.min_depth_samples, min_fraction=cfg.min_depth_fraction
        )
        model = prepare_warp(
            stats,
            depth,
            v.camera,
            max_samples=cfg.max_samples,
            shape_weight=cfg.shape_weight,
            margin=cfg.triangle_margin,
        )
        if not model.usable.any():
            self._usable[i] = False
            self._skip_reason[i] = 'no superpixel has enough depth to be warped'
            return None
        small = stats.n_labels <= np.iinfo(np.int16).max
        bbox = np.maximum(stats.bbox, 0)
        span_off = np.zeros(stats.n_labels + 1, np.int64)
        np.cumsum(bbox[:, 3] - bbox[:, 1] + 1, out=span_off[1:])
        spans = np.empty((span_off[-1], 2), np.int16)
        row_spans(labels, bbox, span_off, spans)
        doubt = _doubt(labels, stats.n_labels, v.confidence)
        c = _ViewCache(
            labels.astype(np.int16) if small else labels, bbox, span_off, spans, model, depth, doubt,
            depth_copied=depth is not v.depth,
        )  # fmt: skip
        self._cache[i] = c
        while len(self._cache) > cfg.max_cached_views:
            self._cache.popitem(last=False)
        return c

    def view_depth(self, i: int) -> NDArray[np.float32]:
        """View ``i``'s depth as rendered (float32 metres): its ``+inf`` sky at ``sky_depth_factor``
        times its largest finite depth (Eq. 14) when that factor is > 0, else as given."""
        v = self.views[i]
        if v.depth is None:
            raise ValueError(f'views[{i}] has no depth')
        depth = np.ascontiguousarray(v.depth, dtype=np.float32)
        f = self.config.sky_depth_factor
        sky = np.isposinf(depth)
        if f > 0 and sky.any():
            finite = depth[np.isfinite(depth) & (depth > 0)]
            if finite.size:
                depth = np.where(sky, np.float32(f * float(finite.max())), depth)
        return depth

    def prepare(self, indices: Sequence[int] | None = None) -> None:
        """Fill the per-view cache now (default: all views, up to ``max_cached_views``)."""
        for i in range(len(self.views)) if indices is None else indices:
            self._view_cache(int(i))

    def cache_nbytes(self) -> int:
        """Bytes held by the per-view cache (labels, boxes, warp models; not the views' rgb/depth)."""
        return sum(c.nbytes for c in self._cache.values())

    @property
    def n_cached(self) -> int:
        return len(self._cache)

    # -- selection ------------------------------------------------------------------------------
    def distance_limit(self) -> float:
        """Largest distance (m) from the nearest usable view at which a query is rendered."""
        if self.config.max_distance_m is not None:
            return float(self.config.max_distance_m)
        return self.config.far_factor * self._scene_depth if math.isfinite(self._scene_depth) else math.inf

    def _candidates(self, t_wn: NDArray[np.float64]) -> tuple[Sequence[int], str | None]:
        """Usable views facing the query direction, nearest first (:class:`NearestFirst`: sorted as
        far as read), or a reason why there are none."""
        idx = np.flatnonzero(self._usable)
        if idx.size == 0:
            return [], 'no usable source views'
        cos = self._axes[idx] @ t_wn[:3, 2]
        idx = idx[cos >= math.cos(math.radians(self.config.max_axis_angle_deg)) - 1e-12]
        if idx.size == 0:
            return [], 'no source view faces the query direction'
        dist = np.linalg.norm(self._centres[idx] - t_wn[:3, 3], axis=1)
        nearest = float(dist.min())
        limit = self.distance_limit()
        if nearest > limit:
            return [], f'query is {nearest:.1f} m from the nearest source view (limit {limit:.1f} m)'
        return NearestFirst(idx, dist), None

    # -- rendering ------------------------------------------------------------------------------
    def _query_pose(self, t_wc: ArrayLike) -> tuple[NDArray[np.float64] | None, Sequence[int], str | None]:
        """Validated pose, candidate views and the reason nothing can be rendered (None: try).

        Raises ValueError for a ``t_wc`` that is not a numeric 4x4 matrix.
        """
        try:
            m = np.asarray(t_wc, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f't_wc must be a numeric 4x4 matrix: {e}') from e
        if m.shape != (4, 4):
            raise ValueError(f't_wc must be a 4x4 matrix, got shape {m.shape}')
        try:
            t_wn = validate_pose(m, field='t_wc')
        except GeometryError as e:
            return None, [], f'invalid pose: {e}'
        cands, reason = self._candidates(t_wn)
        return t_wn, cands, reason

    def refusal(self, t_wc: ArrayLike) -> str | None:
        """Why :meth:`render` would render nothing at pose ``t_wc`` (invalid pose, too far, facing away
        from every view), found without rendering; None when it would try."""
        try:
            return self._query_pose(t_wc)[2]
        except ValueError as e:
            return f'invalid pose: {e}'

    def render(self, t_wc: ArrayLike, camera: PinholeCamera) -> Rendered:
        """Render the view of ``camera`` at camera-to-world pose ``t_wc`` (4x4; see module docstring)."""
        if not isinstance(camera, PinholeCamera):
            raise ValueError(f'camera must be a PinholeCamera, got {type(camera).__name__}')
        t_wn, cands, reason = self._query_pose(t_wc)
        if reason is not None or t_wn is None:
            return Rendered.empty(camera, reason, self.skipped_views)
        out = self._render_views(t_wn, camera, cands)
        if out.reason is None and not out.valid.any():
            return Rendered(
                out.rgb,
                out.valid,
                out.source,
                out.depth,
                out.used_views,
                'nothing of the captured scene is visible from this pose',
                out.skipped_views,
            )
        return out

    def _alloc(self, camera: PinholeCamera) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        h, w = camera.height, camera.width
        return (
            np.empty((h, w, 3), np.uint8),
            np.empty((h, w), np.bool_),
            np.empty((h, w), np.int16),
            np.empty((h, w), np.float32),
        )

    def _render_views(
        self, t_wn: NDArray[np.float64], camera: PinholeCamera, cands: Sequence[int]
    ) -> Rendered:
        """Render from the first usable of ``cands`` (usable views facing ``t_wn``, nearest first).

        ``t_wn``: the validated novel camera-to-world pose. The evaluation baselines
        (:mod:`ibr_ros.core.evaluation.baselines`) override this and share the rest.
        """
        cfg = self.config
        chosen: list[tuple[int, _ViewCache]] = []
        next_view: int | None = None  # the nearest usable view left out (blend='stable')
        for i in cands:
            if len(chosen) == cfg.n_views:
                if cfg.blend != 'stable' or self._view_cache(i) is not None:
                    next_view = i
                    break
                continue
            c = self._view_cache(i)
            if c is not None:
                chosen.append((i, c))
        if not chosen:
            return Rendered.empty(camera, 'no usable source views', self.skipped_views)
        h, w = camera.height, camera.width
        n = len(chosen)
        kmax = max(c.model.n_labels for _, c in chosen)
        pen = np.full((n, kmax), np.inf, np.float32)
        zk = np.full((n, kmax), np.inf, np.float32)
        fit = np.full((n, kmax), np.inf, np.float32)
        inv = np.zeros((n, kmax, 2, 3))
        box = np.zeros((n, kmax, 4), np.int64)
        bbox = np.zeros((n, kmax, 4), np.int32)
        span_off = np.zeros((n, kmax + 1), np.int64)
        orders = []
        max_area = cfg.max_magnification**2
        for j, (i, c) in enumerate(chosen):
            v = self.views[i]
            res = warp_superpixels(c.model, v.camera, v.t_wc, camera, t_wn, cfg.near)
            ok = res.ok.copy()
            kj = ok.size
            affine_maps(c.model.tri, res.vertices, ok, c.bbox, max_area, w, h, inv[j, :kj], box[j, :kj])
            sel = np.flatnonzero(ok)
            orders.append(sel[np.argsort(res.depth[sel], kind='stable')])
            pen[j, :kj] = res.angle_deg
            if cfg.resolution_weight_deg > 0:
                pen[j, :kj] += cfg.resolution_weight_deg * res.resolution
            if cfg.confidence_weight_deg > 0:
                pen[j, :kj] += cfg.confidence_weight_deg * c.doubt
            zk[j, :kj] = res.depth
            fit[j, :kj] = res.fit_px
            bbox[j, :kj] = c.bbox
            span_off[j, : kj + 1] = c.span_off + sum(cc.spans.shape[0] for _, cc in chosen[:j])
        order_off = np.zeros(n + 1, np.int64)
        np.cumsum([o.size for o in orders], out=order_off[1:])
        ids = np.full((n, h, w), -1, np.int16 if kmax <= np.iinfo(np.int16).max else np.int32)
        fb = np.full_like(ids, -1)  # coverage fallback (see raster_views)
        labels = [c.labels for _, c in chosen]
        if len({lab.dtype for lab in labels}) > 1:  # a view with > 32767 superpixels (rare)
            labels = [lab.astype(np.int32) for lab in labels]
        n_bands = 4 * numba.get_num_threads()
        spans = np.concatenate([c.spans for _, c in chosen])
        iters = cfg.depth_lookup_steps
        thr2 = -1.0 if cfg.coverage_px is None else float(cfg.coverage_px) ** 2
        if iters > 0 or thr2 >= 0:
            deps = [c.depth for _, c in chosen]
            rel = np.array(
                [
                    reprojection_params(t_wn, camera, self.views[i].t_wc, self.views[i].camera)
                    for i, _ in chosen
                ]
            )
        else:
            deps, rel = [np.zeros((1, 1), np.float32)], np.zeros((n, 12))
        depths = _four(deps)
        order = np.concatenate(orders)
        raster_views(
            _four(labels),
            depths,
            n,
            bbox,
            span_off,
            spans,
            order,
            order_off,
            inv,
            box,
            rel,
            thr2,
            ids,
            fb,
            n_bands,
        )
        if thr2 >= 0:  # a view's pixels it did not cover: its superpixel that failed only the coverage test
            np.copyto(ids, fb, where=ids < 0)
        out = self._alloc(camera)
        tol = -1.0 if cfg.depth_tolerance is None else float(cfg.depth_tolerance)
        view_ids = np.array([i for i, _ in chosen], np.int16)
        sigma = cfg.stable_sigma_deg if cfg.blend == 'stable' else cfg.soft_sigma_deg
        weights = (BLEND_MODES[cfg.blend], float(sigma), float(cfg.ulr_blend_min_weight))
        gain = np.ones(n, np.float32)
        if cfg.blend == 'stable':
            centres = [self._centres[i] for i, _ in chosen]
            far = None if next_view is None else self._centres[next_view]
            gain[:] = selection_gains(t_wn[:3, 3], centres, far, cfg.stable_fade)
        lookup = (int(iters), float(cfg.depth_lookup_max_px), float(cfg.depth_lookup_min_fit_px))
        rgbs = _four([self.views[i].rgb for i, _ in chosen])
        blend_views(rgbs, depths, n, ids, inv, pen, zk, fit, rel, view_ids, gain, tol, weights, lookup, out)
        if cfg.fill_holes_px > 0:
            fill_small_holes(*out, max_px=cfg.fill_holes_px)
        return Rendered(*out, [i for i, _ in chosen], None, self.skipped_views)
