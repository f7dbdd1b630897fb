# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-view depth refinement (paper Section III-A): MVS -> prune -> mono remap -> MST fusion -> sky.

:class:`DepthRefiner` composes :mod:`mvs`, :mod:`prune`, :mod:`mono`, :mod:`remap`, :mod:`fusion`
and :mod:`sky` and keeps every intermediate map for debugging and evaluation; the result carries a per-pixel
confidence (:mod:`~ibr_ros.core.depth.confidence`). :func:`refine_job` is one step of the
depth_refiner node and ``ibr process``: MVS, then refinement, of one
:class:`~ibr_ros.core.depth.schedule.RefineJob`. Depth maps are float32 z-depth in metres, 0 =
unknown, +inf = sky (the renderer gives it the paper's Eq. 14 depth, or warps it as directions).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.confidence import ConfidenceConfig, depth_confidence
from ibr_ros.core.depth.fusion import fuse_with_support
from ibr_ros.core.depth.job_mvs import PhotometricCache, job_depth
from ibr_ros.core.depth.mono import GroundPlanePrior, MonoModelSpec, OnnxMonoDepth
from ibr_ros.core.depth.mvs import MvsOptions, MvsResult, MvsView, compute_depth_maps
from ibr_ros.core.depth.prune import prune_depth
from ibr_ros.core.depth.remap import lut_remap
from ibr_ros.core.depth.schedule import RefineJob
from ibr_ros.core.depth.sky import OnnxSkySegmenter, SkySpec, erode_sky, sky_fallback
from ibr_ros.core.geometry.plane import fit_ground_plane

__all__ = [
    'DepthRefiner',
    'JobResult',
    'RefineError',
    'RefinedDepth',
    'RefinerConfig',
    'known_depth',
    'refine_job',
]

LOG = logging.getLogger(__name__)

FLAG_SPARSE_MVS = 'sparse_mvs'
FLAG_PLANE_FALLBACK = 'ground_plane_from_pose'


class RefineError(ValueError):
    """A view that cannot be refined (bad shapes, no usable MVS depth to give the mono depth a scale)."""


@dataclass(frozen=True)
class RefinerConfig:
    """Parameters of :class:`DepthRefiner`; defaults follow the paper.

    ``mono``: ``'plane'`` (geometric ground-plane prior, no model) or ``'onnx'`` (``mono_model``).
    ``sky``: ``'fallback'`` (horizon + photometric cues + no MVS depth), ``'onnx'`` (``sky_model``)
    or ``'none'``. ``sky_erosion``: erosion disk diameter as a fraction of the image diagonal.
    ``min_mvs_fraction``: below this fraction of known MVS pixels the result is flagged
    ``sparse_mvs`` (it is still computed while at least ``min_mvs_pixels`` are known).
    ``confidence``: the constants of the per-pixel confidence.
    """

    prune: bool = True
    prune_small: int = 5
    prune_large: int = 31
    prune_sigma_c: float = 0.033
    sigma: float = 0.06
    alpha: float = 1e-5
    mono: Literal['plane', 'onnx'] = 'plane'
    mono_model: MonoModelSpec | None = None
    sky: Literal['fallback', 'onnx', 'none'] = 'fallback'
    sky_model: SkySpec | None = None
    sky_erosion: float = 0.03
    min_mvs_pixels: int = 64
    min_mvs_fraction: float = 0.01
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)

    def __post_init__(self) -> None:
        if self.mono not in ('plane', 'onnx'):
            raise ValueError(f"RefinerConfig.mono must be 'plane' or 'onnx', got {self.mono!r}")
        if self.sky not in ('fallback', 'onnx', 'none'):
            raise ValueError(f"RefinerConfig.sky must be 'fallback', 'onnx' or 'none', got {self.sky!r}")
        if self.mono == 'onnx' and self.mono_model is None:
            raise ValueError("RefinerConfig.mono='onnx' needs mono_model")
        if self.sky == 'onnx' and self.sky_model is None:
            raise ValueError("RefinerConfig.sky='onnx' needs sky_model")
        if self.sigma <= 0 or self.alpha < 0:
            raise ValueError(f'RefinerConfig needs sigma > 0 and alpha >= 0, got {self.sigma}, {self.alpha}')


@dataclass(frozen=True, eq=False)
class RefinedDepth:
    """The final depth of one view and every intermediate map (paper Fig. 3).

    ``depth``: metres, 0 = unknown, +inf = sky; ``confidence``: float32 in [0, 1] per pixel (0 where
    unknown). ``sky`` is the eroded sky mask (+inf in ``depth``), ``sky_raw`` the mask before erosion;
    ``sky_depth`` the paper's finite sky depth (Eq. 14, twice the largest MVS depth) for reference.
    ``implausible``: pixels whose fused depth left the plausible range and became unknown.
    """

    depth: NDArray[np.float32]
    mvs: NDArray[np.float32]
    mvs_pruned: NDArray[np.float32]
    g: NDArray[np.uint16]
    mono_remapped: NDArray[np.float32]
    fused: NDArray[np.float32]
    sky: NDArray[np.bool_]
    sky_depth: float
    confidence: NDArray[np.float32] | None = None
    sky_raw: NDArray[np.bool_] | None = None
    implausible: int = 0
    flags: tuple[str, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def mvs_completeness(self) -> float:
        """Fraction of pixels with pruned MVS depth."""
        return float(np.count_nonzero(self.mvs_pruned > 0)) / self.mvs_pruned.size


def _clean_mvs(d_mvs: NDArray[np.floating], shape: tuple[int, int]) -> NDArray[np.float32]:
    d = np.asarray(d_mvs, dtype=np.float32)
    if d.shape != shape:
        raise RefineError(f'd_mvs has shape {d.shape}, the image is {shape}')
    return np.where(np.isfinite(d) & (d > 0), d, np.float32(0)).astype(np.float32)


def _world_points(view: MvsView, depth: NDArray[np.float32], max_points: int = 20000) -> NDArray[np.float64]:
    v, u = np.nonzero(depth > 0)
    if len(u) > max_points:
        step = len(u) // max_points + 1
        u, v = u[::step], v[::step]
    pc = view.camera.backproject(np.c_[u, v], depth[v, u])
    return pc @ view.t_wc[:3, :3].T + view.t_wc[:3, 3]


def _seed_depth(
    view: MvsView, points_w: NDArray[np.float64], plausible: tuple[float, float] | None
) -> NDArray[np.float32]:
    """Sparse z-depth (metres, 0 unknown) of ``points_w`` in ``view`` (nearest per pixel)."""
    cam = view.camera
    u, v, z = cam.pixels_of(points_w, view.t_wc)
    lo, hi = plausible if plausible is not None else (0.0, np.inf)
    ok = (z > lo) & (z < hi)
    out = np.zeros((cam.height, cam.width), np.float32)
    order = np.argsort(-z[ok])  # far first: the nearest point of a pixel is written last
    out[v[ok][order], u[ok][order]] = z[ok][order]
    return out


class DepthRefiner:
    """Refine the depth of one view from its MVS depth, a monocular prediction and the sky."""

    def __init__(self, config: RefinerConfig | None = None) -> None:
        self.config = config or RefinerConfig()
        c = self.config
        # RefinerConfig guarantees a model for each 'onnx' backend.
        self._mono = OnnxMonoDepth(c.mono_model) if c.mono_model is not None and c.mono == 'onnx' else None
        self._sky = OnnxSkySegmenter(c.sky_model) if c.sky_model is not None and c.sky == 'onnx' else None

    def refine(
        self,
        view: MvsView,
        neighbours: Sequence[MvsView],
        *,
        d_mvs: NDArray[np.floating] | None = None,
        points_w: NDArray[np.floating] | None = None,
        depth_range: tuple[float, float] | None = None,
        mvs: MvsOptions | None = None,
    ) -> RefinedDepth:
        """Refined depth of ``view``; runs MVS (``mvs`` options) with ``neighbours`` unless ``d_mvs``
        is given.

        MVS computes the photometric depth of ``view`` and of every neighbour so that the
        geometric filter can check ``view``'s depth against them (about 5x the cost of one view;
        batch whole keyframe sets with :func:`ibr_ros.core.depth.mvs.compute_depth_maps` instead).
        """
        t0 = time.perf_counter()
        if d_mvs is None:
            if not neighbours:
                raise RefineError('a single view has no neighbours for MVS: pass d_mvs or neighbour views')
            results = compute_depth_maps(
                [view, *neighbours], options=mvs, points_w=points_w, depth_range=depth_range
            )
            if results[0].reason:
                LOG.warning('MVS gave no depth for the view: %s', results[0].reason)
            d_mvs = results[0].depth
        refined = self.refine_from_mvs(view, d_mvs)
        refined.timings_s['mvs'] = time.perf_counter() - t0 - sum(refined.timings_s.values())
        return refined

    def refine_from_mvs(
        self,
        view: MvsView,
        d_mvs: NDArray[np.floating],
        *,
        zncc: NDArray[np.floating] | None = None,
        n_consistent: NDArray[np.integer] | None = None,
        plausible: tuple[float, float] | None = None,
        seeds_w: NDArray[np.floating] | None = None,
    ) -> RefinedDepth:
        """Everything after MVS: prune, sky mask, G, LUT remap, fusion, sky and confidence.

        ``zncc`` / ``n_consistent``: the MVS score and agreeing-view count per pixel (for the
        confidence; None: full). ``plausible``: (near, far) metres the view's depth can take (from
        the SfM points it sees): fused depth outside it becomes unknown (0), never a made-up value.
        ``seeds_w``: world points (Kx3) this view observed in SfM: depth samples where the pruned
        MVS depth has none (textureless lawns, water edges), fused like MVS samples (confidence 0.5:
        no photometric or geometric MVS evidence of their own).
        """
        c = self.config
        rgb = np.asarray(view.rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise RefineError(f'view.rgb must be uint8 HxWx3, got {rgb.dtype} {rgb.shape}')
        shape = rgb.shape[:2]
        if (view.camera.height, view.camera.width) != shape:
            raise RefineError(
                f'view.camera is {view.camera.width}x{view.camera.height}, rgb is {shape[1]}x{shape[0]}'
            )
        timings: dict[str, float] = {}
        flags: list[str] = []
        tick = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal tick
            now = time.perf_counter()
            timings[name] = now - tick
            tick = now

        mvs = _clean_mvs(d_mvs, shape)
        known = int(np.count_nonzero(mvs))
        if known < c.min_mvs_pixels:
            raise RefineError(
                f'd_mvs has {known} known pixels (< {c.min_mvs_pixels}): no scale for the monocular depth'
            )
        pruned = (
            prune_depth(mvs, rgb, small=c.prune_small, large=c.prune_large, sigma_c=c.prune_sigma_c)
            if c.prune
            else mvs
        )
        if np.count_nonzero(pruned) < c.min_mvs_pixels:
            LOG.warning(
                'pruning left fewer than %d MVS pixels: using the unpruned MVS depth', c.min_mvs_pixels
            )
            pruned = mvs
        if np.count_nonzero(pruned) < c.min_mvs_fraction * pruned.size:
            flags.append(FLAG_SPARSE_MVS)
        lap('prune')

        if self._sky is not None:
            sky = self._sky.predict(rgb)
        elif c.sky == 'fallback':
            sky = sky_fallback(rgb, view.camera, view.t_wc, pruned)
        else:
            sky = np.zeros(shape, bool)
        sky_raw = sky
        sky = erode_sky(sky, diag_fraction=c.sky_erosion) if sky.any() else sky
        lap('sky')

        samples = pruned  # depth samples of the LUT and the fusion: MVS, and SfM points where it has none
        if seeds_w is not None and len(seeds_w):
            seeds = _seed_depth(view, np.asarray(seeds_w, np.float64), plausible)
            samples = np.where((pruned > 0) | sky, pruned, seeds).astype(np.float32)
        if self._mono is not None:
            g = self._mono.predict_g(rgb)
        else:
            try:
                plane = fit_ground_plane(_world_points(view, samples))
            except ValueError:
                plane = np.array([0.0, 0.0, 1.0, 0.0])
                flags.append(FLAG_PLANE_FALLBACK)
            g = GroundPlanePrior(plane).predict_g(view.camera, view.t_wc)
        lap('mono')

        mono = lut_remap(g, samples)
        lap('remap')
        fused, support = fuse_with_support(rgb, samples, mono, sigma=c.sigma, alpha=c.alpha)
        lap('fusion')
        sky_depth = 2.0 * float(pruned.max())  # Eq. 14's sky depth, for reference (the sky is +inf)
        final = fused.copy()
        implausible = 0
        if plausible is not None:
            bad = (final > 0) & np.isfinite(final) & ((final < plausible[0]) | (final > plausible[1]))
            implausible = int(np.count_nonzero(bad))
            final[bad] = 0.0
        final[sky] = np.inf
        mvs_px = pruned > 0  # the MVS evidence of a pixel counts where its MVS depth was kept
        confidence = depth_confidence(
            final, samples, mono, support, config=c.confidence,
            zncc=None if zncc is None else np.where(mvs_px, zncc, 0.0),
            n_consistent=None if n_consistent is None else np.where(mvs_px, n_consistent, 0),
        )  # fmt: skip
        lap('sky_confidence')
        return RefinedDepth(
            depth=final,
            mvs=mvs,
            mvs_pruned=pruned,
            g=g,
            mono_remapped=mono,
            fused=fused,
            sky=sky,
            sky_depth=sky_depth,
            confidence=confidence,
            sky_raw=sky_raw,
            implausible=implausible,
            flags=tuple(flags),
            timings_s=timings,
        )


def known_depth(depth: NDArray[np.floating]) -> bool:
    """Whether a depth map (metres; 0, NaN and negative unknown, +inf sky) has at least one finite
    known value; one without is rejected, never published or swapped in (refined or received)."""
    return bool((np.isfinite(depth) & (depth > 0)).any())


@dataclass(frozen=True, eq=False)
class JobResult:
    """What :func:`refine_job` made of one job: ``refined`` is None when it failed.

    ``context``: the neighbour count (and the MVS outcome) for messages; ``error``: why it failed
    ('' when refined); ``timings_s``: seconds of ``mvs`` and ``refine``.
    """

    job: RefineJob
    mvs: MvsResult
    refined: RefinedDepth | None
    context: str
    error: str = ''
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        """MVS + refinement wall time (s)."""
        return sum(self.timings_s.values())


def refine_job(
    refiner: DepthRefiner, job: RefineJob, mvs: MvsOptions, cache: PhotometricCache | None = None
) -> JobResult:
    """MVS of ``job`` (:func:`~ibr_ros.core.depth.job_mvs.job_depth` of its views over its depth
    range, ``mvs`` options; neighbours' photometric depth from ``cache`` where it has them), then
    :meth:`DepthRefiner.refine_from_mvs` of its keyframe.

    A :class:`RefineError` or a result without any known depth (:func:`known_depth`) is a failed
    result, not an exception.
    """
    n = len(job.neighbours)
    t0 = time.perf_counter()
    m = job_depth(job.views, job.stamps, job.depth_range, mvs, probe_range=job.probe_range, cache=cache)
    t1 = time.perf_counter()
    context = f'{n} neighbours, MVS {m.reason or "ok"}'
    try:
        r = refiner.refine_from_mvs(
            job.view, m.depth, zncc=m.confidence, plausible=job.plausible, seeds_w=job.seeds_w,
            n_consistent=m.n_consistent if mvs.backend == 'cpu' else None,  # COLMAP's are not counts
        )  # fmt: skip
    except RefineError as exc:
        return JobResult(
            job, m, None, context, str(exc), {'mvs': t1 - t0, 'refine': time.perf_counter() - t1}
        )
    timings = {'mvs': t1 - t0, 'refine': time.perf_counter() - t1}
    if not known_depth(r.depth):
        return JobResult(job, m, None, f'{n} neighbours', 'no pixel has a known depth', timings)
    return JobResult(job, m, r, context, '', timings)
