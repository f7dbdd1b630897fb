# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Per-view multi-view stereo depth: plane sweep + ZNCC on the CPU, COLMAP-style geometric filter.

Stands in for COLMAP's *geometric* depth maps (Liu et al. 2020, Section III-A) on machines without
CUDA. For one reference view and its source views (:func:`select_neighbours`), :func:`mvs_depth`:

1. **Sweep** at ``sweep_scale`` (default half resolution): fronto-parallel planes ``z = d`` of the
   reference, uniform in inverse depth over ``depth_range`` (about ``plane_step_px`` pixels of
   disparity per plane in the widest-baseline source). A plane maps reference pixels to a source by
   ``H = K_s (R + t n^T / d) K_r^-1`` (``n = (0, 0, 1)``, ``[R | t]`` reference-to-source); each
   source is warped by it (bilinear) and the zero-mean normalised cross-correlation (ZNCC) over a
   ``window`` x ``window`` box comes from running box sums (O(1) per pixel and plane). The plane's
   score is the mean of the ``top_k`` best source ZNCCs (robust to occlusion in the others); the
   winner takes all, with a parabola through its neighbours for sub-plane inverse depth. With
   ``coarse_band`` > 0 (off by default: faster, less precise, see bench/README.md) the full sweep
   runs at half of ``sweep_scale`` over every second plane, and at ``sweep_scale`` each pixel only
   scores its coarse winner +- ``coarse_band`` planes (the ambiguity and range tests below then
   use the coarse sweep).
2. **Propagate**: each pixel picks the best of the inverse depth of its own, its 4 neighbouring
   and the nearest / farthest pixels within ``propagation_radius`` (this pulls background depth
   back over foreground "fattening"), scored at full resolution (default) or at ``sweep_scale``
   (``propagate_at_sweep_scale``). **Refine** at full resolution, every pixel warped by its own
   inverse depth (so windows follow the coarse surface, slanted ground included): offsets of half
   a plane step around it (``refine_steps`` each side, parabola fit), then ``surface_passes`` times
   quarter-step offsets (``surface_steps`` each side) around the 5x5 median of the result.
3. **Reject** pixels whose score is below ``min_zncc``, whose reference window's standard
   deviation is below ``min_std`` grey levels (low texture), whose sweep is ambiguous (another
   score peak more than two planes away within ``min_margin``), whose winner is the first or last
   plane (out of range: the sky matches best at infinity, so it is rejected here), and the
   foreground side of depth edges: pixels more than ``edge_trim_ratio`` nearer (in inverse depth)
   than a kept pixel within ``edge_trim_px``, where window matching smears foreground depth over
   the background.

:func:`geometric_filter` keeps a pixel's depth only where at least ``min_consistent`` other views'
depth maps agree after a forward-backward reprojection (COLMAP's ``filter_min_num_consistent`` and
``filter_geom_consistency_max_cost`` in pixels, plus a relative depth test).
:func:`compute_depth_maps` runs the whole thing for a set of views.

Output depth: float32 z-depth in metres, 0 = unknown (sky, low texture, occlusions, ambiguity).
Pixels: centre of the top-left pixel at (0, 0); poses: 4x4 camera-to-world ``T_wc``
(:mod:`ibr_ros.core.geometry.transforms`). Images must be undistorted
(:mod:`ibr_ros.core.geometry.undistort`).

``backend='colmap'`` runs ``pycolmap.patch_match_stereo`` instead; it needs a CUDA build of
pycolmap and raises :class:`MvsBackendUnavailable` otherwise.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import cv2
import numba
import numpy as np
from numba import njit, prange
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import validate_pose

__all__ = [
    'PROBE_GRID',
    'REASON_NO_DEPTH_RANGE',
    'REASON_NO_OVERLAP',
    'REASON_NO_PARALLAX',
    'REASON_NO_SOURCES',
    'MvsBackendUnavailable',
    'MvsOptions',
    'MvsResult',
    'MvsView',
    'check_camera',
    'compute_depth_maps',
    'depth_range_from_points',
    'geometric_filter',
    'in_view_pixels',
    'mvs_depth',
    'probe_points',
    'select_neighbours',
]

#: Reason flags of an all-zero :class:`MvsResult`: no source views (or no neighbours passed the
#: selection rule), no source sees the reference frustum, the sources' baselines give less than
#: one pixel of disparity over the depth range, no depth range (too few sparse points in view).
REASON_NO_SOURCES = 'no_sources'
REASON_NO_OVERLAP = 'no_overlap'
REASON_NO_PARALLAX = 'no_parallax'
REASON_NO_DEPTH_RANGE = 'no_depth_range'

_STRIP_ROWS = 32  # rows per parallel work item of _sweep
#: Grey level subtracted from the images the sweep kernels see: their float32 box sums stay small.
_GREY_CENTRE = 128.0
#: Windows (reference or source) with a variance below this (grey levels^2) score 0 in the sweep
#: kernels: no texture to correlate (and float32 box sums cannot resolve it).
_MIN_WINDOW_VAR = 0.05

#: Pixel lattice (per side) of :func:`select_neighbours`' probe points without sparse points.
PROBE_GRID = 9


class MvsBackendUnavailable(RuntimeError):  # noqa: N818 (the name the callers use)
    """The requested MVS backend cannot run on this machine (e.g. pycolmap without CUDA)."""


#: The :class:`MvsOptions` fields that are keyword arguments of :func:`select_neighbours`.
_NEIGHBOUR_OPTIONS = (
    'max_neighbours',
    'min_angle_deg',
    'max_angle_deg',
    'target_angle_deg',
    'min_overlap',
    'max_view_angle_deg',
    'side_spread',
    'view_angle_scale_deg',
)


@dataclass(frozen=True)
class MvsOptions:
    """Parameters of :func:`mvs_depth` and :func:`compute_depth_maps` (see the module docstring).

    Sweep: ``n_planes`` (None: ``plane_step_px`` pixels of disparity per plane, clamped to
    ``[min_planes, max_planes]``), ``sweep_scale``, ``window`` (odd, pixels at the sweep scale),
    ``top_k`` best sources averaged, ``coarse_band`` (planes each side of the coarser sweep's winner;
    0 = sweep every plane at ``sweep_scale``). Refinement: ``propagate_at_sweep_scale``,
    ``propagation_radius`` (sweep-scale pixels), ``refine_window`` (odd, full-resolution pixels),
    ``refine_steps`` half-plane offsets each side, ``surface_passes``, ``surface_steps``
    quarter-half-plane offsets each side. Rejection: ``min_zncc`` (aggregated ZNCC, -1..1),
    ``min_std`` (grey levels 0..255), ``min_margin`` (ZNCC), ``edge_trim_px`` (0 = off),
    ``edge_trim_ratio``. Neighbours: the keyword arguments of :func:`select_neighbours`
    (:meth:`neighbour_options`). Geometric filter: ``min_consistent``, ``max_reproj_px``,
    ``max_rel_depth_err`` of :func:`geometric_filter`. Neighbour sweeps of
    :func:`~ibr_ros.core.depth.job_mvs.job_depth` (their depth only confirms the reference's):
    ``neighbour_sources`` source views each, the reference and the best others (0 = up to
    ``max_neighbours`` of the job's views, like the reference); ``neighbour_roi``: each is swept
    only over the pixel box and the depths where the reference's photometric depth projects.
    """

    backend: Literal['cpu', 'colmap'] = 'cpu'
    n_planes: int | None = None
    min_planes: int = 48
    max_planes: int = 192
    plane_step_px: float = 2.0
    sweep_scale: float = 0.5
    window: int = 7
    top_k: int = 2
    refine_window: int = 7
    coarse_band: int = 0
    propagate_at_sweep_scale: bool = False
    refine_steps: int = 3
    propagation_radius: int = 4
    surface_passes: int = 1
    surface_steps: int = 2
    min_zncc: float = 0.5
    min_std: float = 2.0
    min_margin: float = 0.01
    edge_trim_px: int = 4
    edge_trim_ratio: float = 1.08
    max_neighbours: int = 4
    min_angle_deg: float = 2.0
    max_angle_deg: float = 30.0
    target_angle_deg: float = 10.0
    min_overlap: float = 0.3
    max_view_angle_deg: float = 60.0
    side_spread: float = 0.5
    view_angle_scale_deg: float = 30.0
    min_consistent: int = 2
    max_reproj_px: float = 1.0
    max_rel_depth_err: float = 0.01
    neighbour_sources: int = 0
    neighbour_roi: bool = True

    def neighbour_options(self) -> dict[str, Any]:
        """The neighbour settings as keyword arguments of :func:`select_neighbours`."""
        return {name: getattr(self, name) for name in _NEIGHBOUR_OPTIONS}

    def __post_init__(self) -> None:
        def bad(name: str, rule: str) -> ValueError:
            return ValueError(f'MvsOptions.{name} must be {rule}, got {getattr(self, name)!r}')

        if self.backend not in ('cpu', 'colmap'):
            raise bad('backend', "'cpu' or 'colmap'")
        for name in ('window', 'refine_window'):
            if getattr(self, name) < 3 or getattr(self, name) % 2 == 0:
                raise bad(name, 'odd and >= 3')
        if self.n_planes is not None and self.n_planes < 3:
            raise bad('n_planes', '>= 3 or None')
        if not 3 <= self.min_planes <= self.max_planes:
            raise bad('min_planes', f'in [3, max_planes = {self.max_planes}]')
        if not 0.1 <= self.sweep_scale <= 1.0:
            raise bad('sweep_scale', 'in [0.1, 1]')
        for name in ('top_k', 'refine_steps', 'surface_steps', 'max_neighbours', 'min_consistent'):
            if getattr(self, name) < 1:
                raise bad(name, '>= 1')
        for name in (
            'coarse_band',
            'neighbour_sources',
            'propagation_radius',
            'surface_passes',
            'edge_trim_px',
            'min_std',
            'min_angle_deg',
        ):
            if getattr(self, name) < 0:
                raise bad(name, '>= 0')
        if not self.min_angle_deg < self.target_angle_deg < self.max_angle_deg:
            raise bad('target_angle_deg', 'between min_angle_deg and max_angle_deg')
        if not 0 <= self.side_spread < 1:
            raise bad('side_spread', 'in [0, 1)')
        if not self.view_angle_scale_deg >= 0:
            raise bad('view_angle_scale_deg', '>= 0')
        if not self.edge_trim_ratio > 1:
            raise bad('edge_trim_ratio', '> 1')
        for name in ('plane_step_px', 'max_reproj_px', 'max_rel_depth_err', 'max_view_angle_deg'):
            if not getattr(self, name) > 0:
                raise bad(name, 'positive')


@dataclass(frozen=True, eq=False)
class MvsResult:
    """Depth of one reference view.

    ``depth``: HxW float32 z-depth (m), 0 = unknown; ``confidence``: HxW float32 aggregated ZNCC of
    the kept depth (0 where unknown); ``n_consistent``: HxW uint8 number of other views agreeing
    (0 before :func:`geometric_filter`); ``photometric_depth``: the depth before the geometric
    filter; ``neighbours``: the source views used (indices into the caller's list); ``reason``: ''
    or why the depth is all zero (``REASON_*``); ``depth_range``: the (near, far) swept, metres;
    ``n_planes``: the number of planes swept (0 when none were).
    """

    depth: NDArray[np.float32]
    confidence: NDArray[np.float32]
    n_consistent: NDArray[np.uint8]
    photometric_depth: NDArray[np.float32]
    neighbours: tuple[int, ...] = ()
    reason: str = ''
    depth_range: tuple[float, float] = (0.0, 0.0)
    n_planes: int = 0


@dataclass(frozen=True, eq=False)
class MvsView:
    """One registered, undistorted image: HxWx3 uint8 RGB (or HxW grey), its camera and ``T_wc``."""

    rgb: NDArray[np.uint8]
    camera: PinholeCamera
    t_wc: NDArray[np.float64] = field(repr=False)


# --------------------------------------------------------------------------------------------- kernels


@njit(cache=True, parallel=True, nogil=True)
def _box_stats(img, r):
    """Window mean and variance of ``img`` over (2r+1)^2 boxes truncated at the image border."""
    H, W = img.shape
    mean = np.empty((H, W), np.float64)
    var = np.empty((H, W), np.float64)
    for y in prange(H):
        ya, yb = max(0, y - r), min(H, y + r + 1)
        c1 = np.zeros(W)
        c2 = np.zeros(W)
        for yy in range(ya, yb):
            for x in range(W):
                v = np.float64(img[yy, x])
                c1[x] += v
                c2[x] += v * v
        s1 = 0.0
        s2 = 0.0
        for x in range(min(W, r)):
            s1 += c1[x]
            s2 += c2[x]
        for x in range(W):
            if x + r < W:
                s1 += c1[x + r]
                s2 += c2[x + r]
            if x - r - 1 >= 0:
                s1 -= c1[x - r - 1]
                s2 -= c2[x - r - 1]
            cnt = (yb - ya) * (min(W, x + r + 1) - max(0, x - r))
            m = s1 / cnt
            mean[y, x] = m
            var[y, x] = max(s2 / cnt - m * m, 0.0)
    return mean, var


#: LLVM fast-math flags of the sweep kernels: IEEE division and square root (no 'arcp'/'afn'
#: approximations), reassociation and contraction allowed. With ``error_model='numpy'`` (no
#: ZeroDivisionError checks) the per-pixel loops vectorise.
_FASTMATH = {'nnan', 'ninf', 'nsz', 'contract', 'reassoc'}


@njit(cache=True, fastmath=_FASTMATH, error_model='numpy')
def _warp_rows(src, hs, ws, a, b, base, off, ya, yb, out, valid, y0, y1):
    """Rows ``ya:yb`` of one source warped into the reference at inverse depth ``base + off``.

    A reference pixel (u, v) maps to ``a @ (u, v, 1) + rho * b`` (homogeneous source pixel), with
    ``a = K_s R K_r^-1`` and ``b = K_s t``, in float32 (about 1e-4 px at 1000 px). Bilinear, border
    clamped; ``valid`` (rows ``y0:y1``) is False where the centre falls outside the source or behind
    it, or ``rho <= 0``. Per row, a loop that vectorises computes each pixel's top-left tap (flat
    index into ``src``, which must be C-contiguous) and bilinear weights, then a second one reads
    the 4 taps.
    """
    W = out.shape[1]
    f32 = np.float32
    a00, a10, a20 = f32(a[0, 0]), f32(a[1, 0]), f32(a[2, 0])
    b0, b1, b2 = f32(b[0]), f32(b[1]), f32(b[2])
    lo, hx, hy = f32(-0.5), f32(ws - 0.5), f32(hs - 0.5)
    xmax, ymax = f32(ws - 1.001), f32(hs - 1.001)
    zero, tiny = f32(0.0), f32(1e-9)
    stride = src.shape[1]
    flat = src.ravel()
    u1, us, us1 = np.uint32(1), np.uint32(stride), np.uint32(stride + 1)
    tap = np.empty(W, np.uint32)  # unsigned: no negative-index wraparound in the gather loop
    fxs = np.empty(W, np.float32)
    fys = np.empty(W, np.float32)
    ok = np.empty(W, np.bool_)
    for y in range(ya, yb):
        c0 = f32(a[0, 1] * y + a[0, 2])
        c1 = f32(a[1, 1] * y + a[1, 2])
        c2 = f32(a[2, 1] * y + a[2, 2])
        brow = base[y]
        for x in range(W):
            xf = f32(x)
            rho = brow[x] + off
            h2 = a20 * xf + c2 + rho * b2
            front = (h2 > tiny) & (rho > zero)
            inv = f32(1.0) / (h2 if front else f32(1.0))  # finite: no inf/NaN under fast-math
            sx = (a00 * xf + c0 + rho * b0) * inv
            sy = (a10 * xf + c1 + rho * b1) * inv
            ok[x] = front & (lo <= sx) & (sx <= hx) & (lo <= sy) & (sy <= hy)
            qx = min(max(sx, zero), xmax) if front else zero
            qy = min(max(sy, zero), ymax) if front else zero
            x0 = np.int32(qx)
            yi = np.int32(qy)
            tap[x] = np.uint32(yi * stride + x0)
            fxs[x] = qx - f32(x0)
            fys[x] = qy - f32(yi)
        orow = out[y - ya]
        for x in range(W):
            k = tap[x]
            fx = fxs[x]
            t0 = flat[k]
            top = t0 + fx * (flat[k + u1] - t0)
            u0 = flat[k + us]
            bot = u0 + fx * (flat[k + us1] - u0)
            orow[x] = top + fys[x] * (bot - top)
        if y0 <= y < y1:
            valid[y - y0, :] = ok


@njit(inline='always')
def _zncc_score(h0, h1, h2, inv, m, v, ok):
    """ZNCC (float32, clamped to [-1, 1]) of one window from its source sums ``h0``, ``h1``, ``h2``
    (sum, sum of squares, sum of products with the reference), 1 / its area, the reference mean
    ``m`` and variance ``v``; 0 where either window's variance is below ``_MIN_WINDOW_VAR``."""
    f32 = np.float32
    ms = h0 * inv
    vs = h1 * inv - ms * ms
    z = (h2 * inv - m * ms) / math.sqrt(max(v * vs, f32(1e-6)))
    flat = (vs <= f32(_MIN_WINDOW_VAR)) | (v <= f32(_MIN_WINDOW_VAR))
    z = f32(0.0) if flat else min(max(z, f32(-1.0)), f32(1.0))
    return z if ok else f32(-1.0)


@njit(cache=True, fastmath=_FASTMATH, error_model='numpy')
def _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zrow, tops):
    """Windowed ZNCC of the warped rows ``s`` (from row ``ya``) against the reference, rows y0:y1,
    inserted into ``tops`` (k, y1 - y0, W: per pixel the k best scores so far, descending).

    Running column sums (float32 over grey levels centred on ``_GREY_CENTRE``: about 1e-6 relative
    error over a strip; one pass per row adds the entering and subtracts the leaving row) over
    (2r+1)^2 boxes truncated at the image border, the same boxes as :func:`_box_stats`; ``ref``,
    ``s`` and the reference means ``mr`` centred, ``mr`` and ``vr`` float32. Invalid centres score
    -1, flat windows 0. The column sums have r zero columns each side (the
    loops index the views ``d*`` by x: an offset index kept them from vectorising); for r = 3
    (7-pixel windows) the row sums are 7 direct taps in the loop that computes the scores
    (vectorised), otherwise serial running sums into row buffers. ``zrow``: float32, W scores.
    """
    H, W = ref.shape
    Wp = W + 2 * r
    f32 = np.float32
    c0 = np.zeros(Wp, f32)  # column sums, column x at x + r
    c1 = np.zeros(Wp, f32)
    c2 = np.zeros(Wp, f32)
    d0, d1, d2 = c0[r : r + W], c1[r : r + W], c2[r : r + W]  # (indexed by x: loops that vectorise)
    h0 = np.empty(W, f32)
    h1 = np.empty(W, f32)
    h2 = np.empty(W, f32)
    inv_w = np.empty(W, f32)  # 1 / box width at each column
    for x in range(W):
        inv_w[x] = f32(1.0) / f32(min(W, x + r + 1) - max(0, x - r))
    for yy in range(max(0, y0 - r), min(H, y0 + r + 1)):
        srow = s[yy - ya]
        rrow = ref[yy]
        for x in range(W):
            v = srow[x]
            d0[x] += v
            d1[x] += v * v
            d2[x] += v * rrow[x]
    for y in range(y0, y1):
        if y > y0:
            yi, yo = y + r, y - r - 1
            if yi < H and yo >= 0:  # one row enters, one leaves
                si, so = s[yi - ya], s[yo - ya]
                ri, ro = ref[yi], ref[yo]
                for x in range(W):
                    v = si[x]
                    u = so[x]
                    d0[x] += v - u
                    d1[x] += v * v - u * u
                    d2[x] += v * ri[x] - u * ro[x]
            elif yi < H:
                si, ri = s[yi - ya], ref[yi]
                for x in range(W):
                    v = si[x]
                    d0[x] += v
                    d1[x] += v * v
                    d2[x] += v * ri[x]
            elif yo >= 0:
                so, ro = s[yo - ya], ref[yo]
                for x in range(W):
                    u = so[x]
                    d0[x] -= u
                    d1[x] -= u * u
                    d2[x] -= u * ro[x]
        inv_rows = f32(1.0) / f32(min(H, y + r + 1) - max(0, y - r))
        mrow = mr[y]
        vrow = vr[y]
        vld = valid[y - y0]
        if r == 3:
            for x in range(W):
                a0 = c0[x] + c0[x + 1] + c0[x + 2] + c0[x + 3] + c0[x + 4] + c0[x + 5] + c0[x + 6]
                a1 = c1[x] + c1[x + 1] + c1[x + 2] + c1[x + 3] + c1[x + 4] + c1[x + 5] + c1[x + 6]
                a2 = c2[x] + c2[x + 1] + c2[x + 2] + c2[x + 3] + c2[x + 4] + c2[x + 5] + c2[x + 6]
                zrow[x] = _zncc_score(a0, a1, a2, inv_w[x] * inv_rows, mrow[x], vrow[x], vld[x])
        else:
            s0 = 0.0  # float64: serial over the whole row, they would drift in float32
            s1 = 0.0
            s2 = 0.0
            for x in range(2 * r):
                s0 += c0[x]
                s1 += c1[x]
                s2 += c2[x]
            for x in range(W):
                s0 += c0[x + 2 * r]
                s1 += c1[x + 2 * r]
                s2 += c2[x + 2 * r]
                h0[x] = f32(s0)
                h1[x] = f32(s1)
                h2[x] = f32(s2)
                s0 -= c0[x]
                s1 -= c1[x]
                s2 -= c2[x]
            for x in range(W):
                zrow[x] = _zncc_score(h0[x], h1[x], h2[x], inv_w[x] * inv_rows, mrow[x], vrow[x], vld[x])
        for j in range(tops.shape[0]):  # insert into each column's sorted list of the best scores
            tj = tops[j, y - y0]
            for x in range(W):
                hi = max(tj[x], zrow[x])
                zrow[x] = min(tj[x], zrow[x])
                tj[x] = hi


@njit(cache=True, parallel=True, nogil=True, fastmath=_FASTMATH, error_model='numpy')
def _sweep(ref, mr, vr, srcs, sizes, a, b, base, offsets, r, top_k, strip, fit, sep):
    """Score the inverse-depth hypotheses ``base[k] + offsets[k]`` (per-pixel bases, ``base`` of
    shape (1 or len(offsets), H, W): one base for all hypotheses or one each) for every pixel.

    Per hypothesis and source: warp, windowed ZNCC; per hypothesis: mean of the ``top_k`` best
    sources. Per pixel returns the winning hypothesis index (with a parabola offset in [-0.5, 0.5]
    when ``fit``; -1 where nothing scored), its score, and the best score of hypotheses more than
    ``sep`` indices away (-1 if none). Rows are processed in strips of ``strip`` rows in parallel
    (one parallel region for the whole sweep); the per-pixel steps run with columns innermost so
    that they vectorise.
    """
    H, W = ref.shape
    n = srcs.shape[0]
    P = offsets.shape[0]
    nb = base.shape[0]
    k_top = min(top_k, n)
    pos = np.empty((H, W), np.float32)
    best = np.empty((H, W), np.float32)
    second = np.empty((H, W), np.float32)
    n_strips = (H + strip - 1) // strip
    for si in prange(n_strips):
        y0 = si * strip
        y1 = min(H, y0 + strip)
        ya = max(0, y0 - r)
        yb = min(H, y1 + r)
        rows = y1 - y0
        s = np.empty((yb - ya, W), np.float32)
        valid = np.empty((rows, W), np.bool_)
        vol = np.empty((P, rows, W), np.float32)
        tops = np.empty((k_top, rows, W), np.float32)  # per pixel, the k_top best scores, descending
        zrow = np.empty(W, np.float32)
        kb = np.empty(W, np.int64)
        cb = np.empty(W, np.float32)
        c2 = np.empty(W, np.float32)
        for h in range(P):
            tops[:] = -2.0  # below any ZNCC; finite (fast-math ninf)
            for i in range(n):
                hs, ws = sizes[i, 0], sizes[i, 1]
                bh = base[h if nb > 1 else 0]
                _warp_rows(srcs[i], hs, ws, a[i], b[i], bh, offsets[h], ya, yb, s, valid, y0, y1)
                _zncc_rows(ref, mr, vr, s, valid, r, ya, y0, y1, zrow, tops)
            for y in range(rows):
                vh = vol[h, y]
                vh[:] = 0.0
                for j in range(k_top):
                    tj = tops[j, y]
                    for x in range(W):
                        vh[x] += tj[x]
                for x in range(W):
                    vh[x] /= k_top
        for y in range(rows):
            # winner (first of equal scores), then the best more than sep planes away from it
            cb[:] = vol[0, y]
            kb[:] = 0
            for k in range(1, P):
                vk = vol[k, y]
                for x in range(W):
                    better = vk[x] > cb[x]
                    kb[x] = k if better else kb[x]
                    cb[x] = vk[x] if better else cb[x]
            c2[:] = -1.0
            for k in range(P):
                vk = vol[k, y]
                for x in range(W):
                    if abs(k - kb[x]) > sep and vk[x] > c2[x]:
                        c2[x] = vk[x]
            for x in range(W):
                k = kb[x]
                off = 0.0
                if fit and 0 < k < P - 1:
                    cm = vol[k - 1, y, x]
                    cp = vol[k + 1, y, x]
                    den = cm - 2.0 * cb[x] + cp
                    if den < -1e-9:
                        off = min(max(0.5 * (cm - cp) / den, -0.5), 0.5)
                pos[y0 + y, x] = k + off if cb[x] > -1.0 else -1.0
                best[y0 + y, x] = cb[x]
                second[y0 + y, x] = c2[x]
    return pos, best, second


@njit(cache=True)
def _transfer(ka_inv, r_ba, t_ba, kb, u, v, d):
    """Pixel ``(u, v)`` of camera a at z-depth ``d`` seen by camera b: ``(u_b, v_b, z_b)``.

    ``ka_inv``: a's inverse intrinsics; ``r_ba``, ``t_ba``: a's frame into b's; ``kb``: b's intrinsics
    (skew allowed). ``u_b, v_b`` are meaningless when ``z_b <= 1e-9`` (behind b).
    """
    px = (ka_inv[0, 0] * u + ka_inv[0, 1] * v + ka_inv[0, 2]) * d
    py = (ka_inv[1, 0] * u + ka_inv[1, 1] * v + ka_inv[1, 2]) * d
    qx = r_ba[0, 0] * px + r_ba[0, 1] * py + r_ba[0, 2] * d + t_ba[0]
    qy = r_ba[1, 0] * px + r_ba[1, 1] * py + r_ba[1, 2] * d + t_ba[1]
    qz = r_ba[2, 0] * px + r_ba[2, 1] * py + r_ba[2, 2] * d + t_ba[2]
    if qz <= 1e-9:
        return 0.0, 0.0, qz
    return (kb[0, 0] * qx + kb[0, 1] * qy) / qz + kb[0, 2], (kb[1, 1] * qy) / qz + kb[1, 2], qz


@njit(cache=True, parallel=True)
def _consistency(d_i, ki, ki_inv, r_ji, t_ji, d_j, kj, kj_inv, r_ij, t_ij, max_px, max_rel, count):
    """Add 1 to ``count`` where view j's depth agrees with view i's after a forward-backward trip.

    A pixel of i at depth d goes to 3D, into j, back to 3D at j's depth there (inverse depth
    interpolated bilinearly when the 4 pixels around are known, else the nearest pixel's) and into
    i: it agrees when it lands within ``max_px`` pixels of where it started with a z-depth within
    ``max_rel`` (relative) of d. Depths must be finite (0 = unknown).
    """
    H, W = d_i.shape
    hj, wj = d_j.shape
    for y in prange(H):
        for x in range(W):
            d = d_i[y, x]
            if not d > 0.0:
                continue
            uj, vj, qz = _transfer(ki_inv, r_ji, t_ji, kj, x, y, d)
            if qz <= 1e-9:
                continue
            if not (-0.5 <= uj < wj - 0.5 and -0.5 <= vj < hj - 0.5):
                continue
            dj = d_j[math.floor(vj + 0.5), math.floor(uj + 0.5)]
            if not dj > 0.0:
                continue
            x0 = min(max(math.floor(uj), 0), wj - 2)
            y0 = min(max(math.floor(vj), 0), hj - 2)
            q00, q01, q10, q11 = d_j[y0, x0], d_j[y0, x0 + 1], d_j[y0 + 1, x0], d_j[y0 + 1, x0 + 1]
            if q00 > 0.0 and q01 > 0.0 and q10 > 0.0 and q11 > 0.0:  # bilinear in inverse depth
                fx = min(max(uj - x0, 0.0), 1.0)
                fy = min(max(vj - y0, 0.0), 1.0)
                top = 1.0 / q00 + fx * (1.0 / q01 - 1.0 / q00)
                bot = 1.0 / q10 + fx * (1.0 / q11 - 1.0 / q10)
                dj = 1.0 / (top + fy * (bot - top))
            u2, v2, bz = _transfer(kj_inv, r_ij, t_ij, ki, uj, vj, dj)
            if bz <= 1e-9:
                continue
            if (u2 - x) ** 2 + (v2 - y) ** 2 <= max_px * max_px and abs(bz - d) <= max_rel * d:
                count[y, x] += 1


# --------------------------------------------------------------------------------------------- helpers


def _grey(name: str, img: ArrayLike, cam: PinholeCamera) -> NDArray[np.float32]:
    """HxW float32 grey levels 0..255 of an RGB or grey image, checked against the camera size."""
    a = np.asarray(img)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (1, 3)):
        raise ValueError(f'{name} must be an HxW or HxWx3 image, got shape {a.shape}')
    if a.shape[:2] != (cam.height, cam.width):
        raise ValueError(
            f'{name} is {a.shape[1]}x{a.shape[0]} pixels but its camera is {cam.width}x{cam.height}'
        )
    g = a.astype(np.float32)
    if a.dtype.kind == 'f':
        g = np.nan_to_num(g, nan=0.0) * (255.0 if float(np.nanmax(a, initial=0.0)) <= 1.0 else 1.0)
    if a.ndim == 3 and a.shape[2] == 3:
        g = np.asarray(cv2.cvtColor(g, cv2.COLOR_RGB2GRAY), np.float32)
    return np.ascontiguousarray(g.reshape(cam.height, cam.width))


def check_camera(name: str, cam: object) -> PinholeCamera:
    """``cam`` if it is an undistorted :class:`PinholeCamera`; else ValueError naming ``name``."""
    if not isinstance(cam, PinholeCamera):
        raise ValueError(f'{name} must be a PinholeCamera, got {type(cam).__name__}')
    if cam.is_distorted:
        raise ValueError(f'{name} has distortion {cam.d.tolist()}: undistort the images first')
    return cam


def _cameras(name: str, cams: PinholeCamera | Sequence[PinholeCamera], n: int) -> list[PinholeCamera]:
    """``n`` checked cameras: one camera shared by all views, or one per view."""
    seq = [cams] * n if isinstance(cams, PinholeCamera) else list(cams)
    if len(seq) != n:
        raise ValueError(f'{name} has {len(seq)} cameras for {n} views')
    return [check_camera(f'{name}[{i}]', c) for i, c in enumerate(seq)]


def _poses(name: str, poses: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
    """Checked Nx4x4 camera-to-world poses (``n`` of them when given)."""
    arr = np.asarray(poses, dtype=np.float64)
    if arr.size == 0 and n == 0:
        return np.zeros((0, 4, 4))
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f'{name} must be Nx4x4 camera-to-world matrices, got shape {arr.shape}')
    if n is not None and len(arr) != n:
        raise ValueError(f'{name} has {len(arr)} poses for {n} views')
    r = arr[:, :3, :3]
    with np.errstate(invalid='ignore'):
        err = np.abs(np.matmul(np.swapaxes(r, 1, 2), r) - np.eye(3)).max(axis=(1, 2), initial=0.0)
        ok = np.isfinite(arr).all(axis=(1, 2)) & (err <= 1e-4) & (np.abs(np.linalg.det(r) - 1.0) <= 1e-4)
        ok &= np.isclose(arr[:, 3], [0, 0, 0, 1]).all(axis=1)
    for i in np.flatnonzero(~ok):  # validate_pose raises naming the first bad pose
        validate_pose(arr[i], field=f'{name}[{i}]')
    return arr


def _relative(t_wr: NDArray[np.float64], t_ws: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Rotation and translation taking reference-camera points to source-camera points."""
    t_sr = np.linalg.inv(t_ws) @ t_wr
    return t_sr[:3, :3], t_sr[:3, 3]


def in_view_pixels(
    points_w: NDArray[np.float64], camera: PinholeCamera, t_wc: NDArray[np.float64]
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
    """(mask of the world points (Nx3) that lie in front of the camera at ``t_wc`` and project inside
    its image, their z-depths in metres, their Nx2 pixels; NaN behind the camera)."""
    pc = (points_w - t_wc[:3, 3]) @ t_wc[:3, :3]
    uv, z = camera.project(pc)
    with np.errstate(invalid='ignore'):
        ok = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5)
        ok &= (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5)
    return ok, z, uv


def _in_view(points_w: NDArray[np.float64], camera: PinholeCamera, t_wc: NDArray[np.float64]):
    """(mask of world points that project inside the image in front of the camera, their z-depths)."""
    ok, z, _ = in_view_pixels(points_w, camera, t_wc)
    return ok, z


def _in_views(
    points_w: NDArray[np.float64], cameras: Sequence[PinholeCamera], t_wcs: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(views, points) mask of :func:`_in_view` for several views at once."""
    if not cameras:
        return np.zeros((0, len(points_w)), bool)
    pc = np.matmul(points_w[None] - t_wcs[:, None, :3, 3], t_wcs[:, :3, :3])
    k = np.array([(c.fx, c.fy, c.cx, c.cy, c.width, c.height) for c in cameras])[:, :, None]
    z = pc[..., 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        u = pc[..., 0] / z * k[:, 0] + k[:, 2]
        v = pc[..., 1] / z * k[:, 1] + k[:, 3]
        ok = (z > 0) & (u >= -0.5) & (u <= k[:, 4] - 0.5) & (v >= -0.5) & (v <= k[:, 5] - 0.5)
    return np.asarray(ok, dtype=bool)


def _masked_median(values: NDArray[np.float64], mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Median of each row of ``values`` over its ``mask``-ed entries (NaN for an empty row)."""
    if values.shape[0] == 0:
        return np.zeros(0)
    srt = np.sort(np.where(mask, values, np.inf), axis=1)
    n = mask.sum(axis=1)
    rows = np.arange(len(n))
    lo = srt[rows, np.maximum((n - 1) // 2, 0)]
    hi = srt[rows, np.maximum(n // 2, 0)]
    return np.where(n > 0, np.where(n % 2 == 1, lo, (lo + hi) / 2), np.nan)


def _points(points_w: ArrayLike) -> NDArray[np.float64]:
    pts = np.asarray(points_w, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f'points_w must be Nx3 world points, got shape {pts.shape}')
    return pts[np.all(np.isfinite(pts), axis=1)]


def probe_points(
    camera: PinholeCamera, t_wc: NDArray[np.float64], depth: float, grid: int = PROBE_GRID
) -> NDArray[np.float64]:
    """World points (Mx3 m) of a ``grid`` x ``grid`` pixel lattice of the view at z-depth ``depth``
    (m); with the default :data:`PROBE_GRID`, the scene :func:`select_neighbours` probes given a
    depth range."""
    us = np.linspace(0, camera.width - 1, grid)
    vs = np.linspace(0, camera.height - 1, grid)
    uv = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2)
    return camera.backproject(uv, np.full(len(uv), depth)) @ t_wc[:3, :3].T + t_wc[:3, 3]


def _angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angle in degrees between the rows (last axis) of ``a`` and ``b``."""
    c = np.sum(a * b, axis=-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _empty(shape: tuple[int, int], reason: str, neighbours: Sequence[int] = (), rng=(0.0, 0.0)) -> MvsResult:
    z = np.zeros(shape, np.float32)
    return MvsResult(z, z.copy(), np.zeros(shape, np.uint8), z.copy(), tuple(neighbours), reason, rng)


class _Stack:
    """Grey reference and source images at one scale, with the maps of :func:`_warp_rows`."""

    def __init__(self, ref, ref_cam: PinholeCamera, t_wr, greys, cams, t_ws) -> None:
        self.ref = ref
        self._ref_c = ref - np.float32(_GREY_CENTRE)  # the kernels' input
        self._stats: dict[int, tuple[NDArray, ...]] = {}
        n = len(greys)
        self.srcs = np.zeros((n, max(g.shape[0] for g in greys), max(g.shape[1] for g in greys)), np.float32)
        self.sizes = np.zeros((n, 2), np.int64)
        self.a = np.empty((n, 3, 3))
        self.b = np.empty((n, 3))
        k_inv = np.linalg.inv(ref_cam.k)
        for i, (g, c, t) in enumerate(zip(greys, cams, t_ws)):
            self.srcs[i, : g.shape[0], : g.shape[1]] = g - np.float32(_GREY_CENTRE)  # kernels' input
            self.sizes[i] = g.shape
            r, tt = _relative(t_wr, t)
            self.a[i] = c.k @ r @ k_inv
            self.b[i] = c.k @ tt

    def disparity_span(self, rho: tuple[float, float]) -> float:
        """Largest distance (px) in any source between a pixel's matches at the two inverse depths."""
        H, W = self.ref.shape
        us, vs = np.meshgrid(np.linspace(0, W - 1, 7), np.linspace(0, H - 1, 7))
        p = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)])
        span = 0.0
        for a, b in zip(self.a, self.b):
            h = [a @ p + r * b[:, None] for r in rho]
            ok = (h[0][2] > 1e-9) & (h[1][2] > 1e-9)
            if ok.any():
                d = h[0][:2, ok] / h[0][2, ok] - h[1][:2, ok] / h[1][2, ok]
                span = max(span, float(np.linalg.norm(d, axis=0).max()))
        return span

    def box_stats(self, win: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The reference's mean and variance (float64) over ``win`` x ``win`` windows (computed once)."""
        if win not in self._stats:
            mean, var = _box_stats(self.ref, win // 2)
            c = np.float32(_GREY_CENTRE)
            self._stats[win] = (mean, var, (mean - c).astype(np.float32), var.astype(np.float32))
        mean, var = self._stats[win][:2]
        return mean, var

    def sweep(self, base: NDArray, offsets: ArrayLike, win: int, o: MvsOptions, fit: bool = True):
        """(position, best, second-best) of :func:`_sweep` with ``win`` x ``win`` windows for the
        hypotheses ``base + offsets[k]`` (``base``: (H, W) inverse depths) or ``base[k] + offsets[k]``
        (``base``: (len(offsets), H, W), several maps scored in one pass over the strips; cheaper
        than one call each).

        Strips are handed out one at a time (dynamic scheduling) so that a thread descheduled on a
        busy machine does not hold the others up.
        """
        base = np.ascontiguousarray(base, dtype=np.float32)
        offsets = np.asarray(offsets, dtype=np.float32).reshape(-1)
        base = base[None] if base.ndim == 2 else base
        if base.ndim != 3 or base.shape[0] not in (1, offsets.size) or base.shape[1:] != self.ref.shape:
            raise ValueError(
                f'sweep: base of shape {base.shape} for {offsets.size} offsets, image {self.ref.shape}'
            )
        if not (np.isfinite(base).all() and np.isfinite(offsets).all()):
            raise ValueError('sweep: base and offsets (inverse depths) must be finite: the kernels assume it')
        self.box_stats(win)
        mean, var = self._stats[win][2:]
        with numba.parallel_chunksize(1):
            return _sweep(
                self._ref_c, mean, var, self.srcs, self.sizes, self.a, self.b, base, offsets,
                win // 2, o.top_k, _STRIP_ROWS, fit, 2,
            )  # fmt: skip


def _scaled(cam: PinholeCamera, s: float) -> PinholeCamera:
    """The camera of the image resized to ``round(s * size)`` pixels (exact per-axis factors)."""
    w, h = max(2, round(cam.width * s)), max(2, round(cam.height * s))
    return cam.scaled(w / cam.width, h / cam.height)


def _candidates(rho_s: NDArray[np.float32], shifts: bool, radius: int) -> list[NDArray[np.float32]]:
    """Propagation candidates of an inverse-depth map: its 4 neighbours' values (``shifts``) and the
    largest / smallest known value within ``radius`` pixels."""
    cands = (
        [np.roll(rho_s, (dy, dx), axis=(0, 1)) for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0))]
        if shifts
        else []
    )
    if radius > 0:
        ker = np.ones((2 * radius + 1,) * 2, np.uint8)
        cands += [
            np.asarray(cv2.dilate(rho_s, ker), np.float32),
            np.asarray(cv2.erode(np.where(rho_s > 0, rho_s, np.float32(1e9)), ker), np.float32),
        ]
    return cands


def _scaled_stack(ref, ref_cam: PinholeCamera, t_wr, greys, cams, t_ws, sc: float) -> _Stack:
    """The :class:`_Stack` of the images resized by ``sc`` (area interpolation; as given at 1)."""
    if sc >= 1:
        return _Stack(ref, ref_cam, t_wr, greys, cams, t_ws)
    cam_s = _scaled(ref_cam, sc)
    cams_s = [_scaled(c, sc) for c in cams]
    ref_s = cv2.resize(ref, (cam_s.width, cam_s.height), interpolation=cv2.INTER_AREA)
    greys_s = [
        cv2.resize(g, (c.width, c.height), interpolation=cv2.INTER_AREA) for g, c in zip(greys, cams_s)
    ]
    return _Stack(ref_s, cam_s, t_wr, greys_s, cams_s, t_ws)


@dataclass(frozen=True, eq=False)
class _PlaneSweep:
    """Step 1's result: the winning plane's inverse depth (1/m, 0 where nothing scored) and the
    rejected pixels at the sweep scale, the inverse depth from one plane to the next (negative:
    near to far), the number of planes and, with ``propagate_at_sweep_scale``, the
    inverse depth after propagation at the sweep scale."""

    rho: NDArray[np.float32]
    rejected: NDArray[np.bool_]
    step: float
    n_planes: int
    propagated: NDArray[np.float32] | None = None


def _plane_sweep(
    ref, ref_cam, t_wr, greys, cams, t_ws, near: float, far: float, o: MvsOptions, window=None
) -> _PlaneSweep | str:
    """Step 1 of the module docstring on checked grey images: its result or a reason.

    ``window``: (near, far) z-depths: only the planes of the sweep over (near, far) that lie within
    it, and 2 more each side, are swept (``coarse_band`` 0 only).
    """
    rho_near, rho_far = 1.0 / near, 1.0 / far
    s = o.sweep_scale
    coarse = _scaled_stack(ref, ref_cam, t_wr, greys, cams, t_ws, s)
    span = coarse.disparity_span((rho_near, rho_far))
    if span < 1.0:
        return REASON_NO_PARALLAX
    n_planes = o.n_planes or int(min(max(math.ceil(span / o.plane_step_px) + 1, o.min_planes), o.max_planes))
    step = (rho_far - rho_near) / (n_planes - 1)

    # every plane at sweep_scale, or (coarse_band) every second plane at half of it, then each
    # pixel's winner +- coarse_band planes at sweep_scale
    hc, wc = coarse.ref.shape
    if o.coarse_band > 0 and min(hc, wc) >= 16:
        top = _scaled_stack(ref, ref_cam, t_wr, greys, cams, t_ws, 0.5 * s)
        n_top = max(3, (n_planes + 2) // 2)
        step_top = (rho_far - rho_near) / (n_top - 1)
        planes = rho_near + step_top * np.arange(n_top)
        pos, best, second = top.sweep(np.zeros(top.ref.shape), planes, o.window, o)
        rho_t = np.where(pos >= 0, rho_near + pos * step_top, 0.0).astype(np.float32)
        bad_t = ((pos < 0.5) | (pos > n_top - 1.5) | (best - second < o.min_margin)).astype(np.uint8)
        base = cv2.resize(rho_t, (wc, hc), interpolation=cv2.INTER_NEAREST)
        band = o.coarse_band
        pos, _, _ = coarse.sweep(base, np.arange(-band, band + 1) * step, o.window, o)
        rho_s = np.where(pos >= 0, base + (pos - band) * np.float32(step), 0.0).astype(np.float32)
        bad_s = cv2.resize(bad_t, (wc, hc), interpolation=cv2.INTER_NEAREST).astype(bool) | (pos < 0)
    else:
        k0, k1 = 0, n_planes - 1
        if window is not None:  # planes within the window's inverse depths, 2 more each side
            k_near = (1.0 / window[0] - rho_near) / step  # plane indices (fractional) of its ends
            k_far = (1.0 / window[1] - rho_near) / step
            k0 = min(max(0, math.floor(k_near) - 2), n_planes - 1)
            k1 = max(min(n_planes - 1, math.ceil(k_far) + 2), 0)
            if k1 - k0 < 4:  # (almost) outside the range: at least 5 planes
                k0 = max(0, min(k0, k1 - 4, n_planes - 5))
                k1 = min(n_planes - 1, k0 + 4)
        planes = rho_near + step * np.arange(k0, k1 + 1)
        pos, best, second = coarse.sweep(np.zeros(coarse.ref.shape), planes, o.window, o)
        rho_s = np.where(pos >= 0, rho_near + (pos + k0) * step, 0.0).astype(np.float32)
        bad_s = (pos < 0.5) | (pos > len(planes) - 1.5) | (best - second < o.min_margin)
    propagated = None
    if o.propagate_at_sweep_scale:
        propagated = _best_of(coarse, [rho_s, *_candidates(rho_s, s < 1, o.propagation_radius)], o.window, o)
    return _PlaneSweep(rho_s, bad_s, step, n_planes, propagated)


def _best_of(stack: _Stack, maps: list[NDArray], win: int, o: MvsOptions) -> NDArray[np.float32]:
    """Per pixel the first of ``maps`` (inverse depths) with the best score, all scored in one sweep
    (the winner of :func:`_sweep`: first of equal scores; the first map where none scores)."""
    bases = np.stack(maps, dtype=np.float32)
    pos, _, _ = stack.sweep(bases, np.zeros(len(maps)), win, o, False)
    k = np.maximum(pos, 0).astype(np.intp)
    return np.take_along_axis(bases, k[None], axis=0)[0]


def _sweep_and_refine(
    ref, ref_cam, t_wr, greys, cams, t_ws, near: float, far: float, o: MvsOptions, window=None
):
    """Steps 1-3 of the module docstring on checked grey images: (depth, score, n_planes) or a reason.

    ``window``: (near, far) z-depths: only the planes of the sweep over (near, far) that lie within
    it, and 2 more each side, are swept (``coarse_band`` 0 only).
    """
    ps = _plane_sweep(ref, ref_cam, t_wr, greys, cams, t_ws, near, far, o, window)
    if isinstance(ps, str):
        return ps
    H, W = ref.shape
    low = ps.rho.shape != (H, W)  # swept below full resolution

    def up(a: NDArray) -> NDArray:
        return cv2.resize(a, (W, H), interpolation=cv2.INTER_NEAREST) if low else a

    # 2. propagate (at sweep_scale, done in step 1, or full resolution), refine at full resolution
    fine = _Stack(ref, ref_cam, t_wr, greys, cams, t_ws)
    if ps.propagated is not None:
        base = up(ps.propagated)
    else:
        cands = _candidates(ps.rho, low, o.propagation_radius)
        base = _best_of(fine, [up(ps.rho), *map(up, cands)], o.refine_window, o)
    half = 0.5 * ps.step
    pos, score, _ = fine.sweep(
        base, np.arange(-o.refine_steps, o.refine_steps + 1) * half, o.refine_window, o
    )
    valid = pos >= 0
    rho = base + (pos - o.refine_steps) * np.float32(half)
    for _ in range(o.surface_passes):
        base = cv2.medianBlur(np.where(valid, rho, 0).astype(np.float32), 5)
        k = o.surface_steps
        pos, score, _ = fine.sweep(base, np.arange(-k, k + 1) * 0.25 * half, o.refine_window, o)
        valid &= pos >= 0
        rho = base + (pos - k) * np.float32(0.25 * half)

    # 3. reject
    bad = up(ps.rejected.astype(np.uint8)).astype(bool) | ~valid | ~(rho > 0.999 / far)
    bad |= (score < o.min_zncc) | (fine.box_stats(o.refine_window)[1] < o.min_std**2)
    if o.edge_trim_px > 0:
        ker = np.ones((2 * o.edge_trim_px + 1,) * 2, np.uint8)
        bad |= cv2.erode(np.where(bad, 1e9, rho).astype(np.float32), ker) * o.edge_trim_ratio < rho
    depth = np.where(bad, 0.0, 1.0 / np.where(bad, 1.0, rho)).astype(np.float32)
    return depth, np.where(bad, 0.0, score).astype(np.float32), ps.n_planes


# --------------------------------------------------------------------------------------------- public


def depth_range_from_points(
    points_w: ArrayLike,
    camera: PinholeCamera,
    t_wc: ArrayLike,
    *,
    percentiles: tuple[float, float] = (1.0, 99.0),
    margin: tuple[float, float] = (0.75, 1.5),
    min_points: int = 10,
) -> tuple[float, float] | None:
    """(near, far) metres from the z-depths of the world points ``points_w`` (Nx3) seen in the view.

    The ``percentiles`` of the depths of points inside the image, times ``margin``; None when fewer
    than ``min_points`` points are visible.
    """
    pts = _points(points_w)
    ok, z = _in_view(pts, camera, validate_pose(t_wc, field='t_wc'))
    if ok.sum() < min_points:
        return None
    lo, hi = np.percentile(z[ok], percentiles)
    return float(lo * margin[0]), float(hi * margin[1])


def select_neighbours(
    ref_index: int,
    poses: ArrayLike,
    cameras: PinholeCamera | Sequence[PinholeCamera],
    *,
    points_w: ArrayLike | None = None,
    depth_range: tuple[float, float] | None = None,
    max_neighbours: int = 4,
    min_angle_deg: float = 2.0,
    max_angle_deg: float = 30.0,
    target_angle_deg: float = 10.0,
    min_overlap: float = 0.3,
    max_view_angle_deg: float = 60.0,
    side_spread: float = 0.5,
    view_angle_scale_deg: float = 30.0,
) -> list[int]:
    """Indices of up to ``max_neighbours`` source views for view ``ref_index``, best first.

    Rule: the reference's scene is represented by probe points, its visible sparse ``points_w``
    (at least 10; subsampled to ~2000), else a 9x9 pixel grid at the geometric mean of
    ``depth_range``. A candidate view is kept when

    * its optical axis is within ``max_view_angle_deg`` of the reference's (not facing away),
    * at least ``min_overlap`` of the probe points project into it (frustum overlap), and
    * the median triangulation angle at the probe points it sees, between the rays from the two
      camera centres, lies in ``[min_angle_deg, max_angle_deg]``.

    Score = overlap x ``exp(-((angle - target) / target)^2 / 2)`` x ``exp(-(v / s)^2 / 2)``, ``v``
    the angle between the candidate's and the reference's optical axes and ``s`` =
    ``view_angle_scale_deg`` (0: no such factor): of two views with the same parallax, the one
    looking the same way wins. Views are picked greedily by score, a candidate's score scaled

    * by ``min(1, a / min_angle_deg)`` for each already picked view, ``a`` the angle between the two
      seen from the probe centroid (the picks do not repeat one baseline), and
    * by ``1 - side_spread x (1 + c) / 2``, ``c`` the largest cosine between its side and an
      already picked view's side; a view's side is the direction of its baseline (its centre minus
      the reference's) projected onto the reference image plane (no side, ``c`` = 0, when the
      baseline is along the optical axis). A candidate on the side of a pick is scaled by
      ``1 - side_spread``, one at right angles by ``1 - side_spread / 2``, one opposite every pick
      by 1: the picks surround the reference where the flight allows.

    Ties go to the lower index. Raises ValueError without probe points.
    """
    t_all = _poses('poses', poses)
    n = len(t_all)
    if not 0 <= ref_index < n:
        raise ValueError(f'ref_index {ref_index} is out of range for {n} poses')
    cams = _cameras('cameras', cameras, n)
    t_ref = t_all[ref_index]
    probes = None
    if points_w is not None:
        pts = _points(points_w)
        ok, _ = _in_view(pts, cams[ref_index], t_ref)
        if ok.sum() >= 10:
            probes = pts[ok][:: max(1, int(ok.sum()) // 2000)]
    if probes is None:
        if depth_range is None:
            raise ValueError('select_neighbours needs depth_range or points_w with 10 or more points in view')
        probes = probe_points(cams[ref_index], t_ref, math.sqrt(depth_range[0] * depth_range[1]))
    centroid = probes.mean(axis=0)
    # Candidates, all views at once: viewing direction, overlap, median triangulation angle.
    view_angle = _angle_deg(t_ref[:3, 2], t_all[:, :3, 2])
    js = np.flatnonzero(view_angle <= max_view_angle_deg)
    js = js[js != ref_index]
    vis = _in_views(probes, [cams[j] for j in js], t_all[js])
    overlap = vis.mean(axis=1)
    keep = (overlap >= min_overlap) & vis.any(axis=1)
    js, vis, overlap = js[keep], vis[keep], overlap[keep]
    tri = _angle_deg(t_ref[:3, 3] - probes, t_all[js, None, :3, 3] - probes)  # (candidates, probes)
    ang = _masked_median(tri, vis)
    keep = (min_angle_deg <= ang) & (ang <= max_angle_deg)
    js, overlap, ang = js[keep], overlap[keep], ang[keep]
    score = np.array([
        o * math.exp(-0.5 * ((a - target_angle_deg) / target_angle_deg) ** 2)
        * (math.exp(-0.5 * (float(v) / view_angle_scale_deg) ** 2) if view_angle_scale_deg > 0 else 1.0)
        for o, a, v in zip(overlap.tolist(), ang.tolist(), view_angle[js].tolist())
    ])  # fmt: skip
    # Sides: unit baseline directions in the reference image plane (camera x right, y down).
    side = ((t_all[js, :3, 3] - t_ref[:3, 3]) @ t_ref[:3, :3])[:, :2]
    norm = np.linalg.norm(side, axis=1)
    side = np.where(norm[:, None] > 1e-9, side / np.maximum(norm, 1e-300)[:, None], 0.0)
    # Greedy picks: each pick scales the others by their baseline angle to it and their side.
    rays = t_all[js, :3, 3] - centroid
    open_ = np.ones(len(js), bool)
    closest = np.full(len(js), -np.inf)  # largest side cosine to a pick so far
    picked: list[int] = []
    while open_.any() and len(picked) < max_neighbours:
        scores = score if not picked else score * (1.0 - side_spread * (1.0 + closest) / 2.0)
        best = int(np.flatnonzero(open_)[np.argmax(scores[open_])])
        picked.append(int(js[best]))
        open_[best] = False
        a = _angle_deg(rays, rays[best])
        score = score * np.minimum(1.0, a / max(min_angle_deg, 1e-6))
        closest = np.maximum(closest, side[:, 0] * side[best, 0] + side[:, 1] * side[best, 1])
    return picked


def mvs_depth(
    ref_rgb: ArrayLike,
    ref_cam: PinholeCamera,
    ref_pose: ArrayLike,
    src_rgbs: Sequence[ArrayLike],
    src_cams: PinholeCamera | Sequence[PinholeCamera],
    src_poses: ArrayLike,
    *,
    depth_range: tuple[float, float] | None = None,
    points_w: ArrayLike | None = None,
    options: MvsOptions | None = None,
    sweep_window: tuple[float, float] | None = None,
) -> MvsResult:
    """Photometric depth of the reference view from its source views (see the module docstring).

    ``depth_range`` (near, far) in metres, or ``points_w`` (Nx3 world points, e.g. SfM points) to
    derive it with :func:`depth_range_from_points`. ``src_cams`` is one camera for all sources or
    one per source. The result's ``depth`` equals its ``photometric_depth`` (no geometric filter)
    and ``neighbours`` lists the sources that overlap the reference. An all-zero result carries a
    ``reason`` (``REASON_*``); bad arguments raise ValueError naming them. ``sweep_window`` (near,
    far) z-depths (m): only the planes of the sweep over the depth range that lie within it (and 2
    more each side) are swept; pixels whose best plane is at its ends are rejected (out of the
    window). Ignored with ``coarse_band`` > 0.
    """
    o = options or MvsOptions()
    ref_cam = check_camera('ref_cam', ref_cam)
    ref = _grey('ref_rgb', ref_rgb, ref_cam)
    t_wr = validate_pose(ref_pose, field='ref_pose')
    if isinstance(src_rgbs, np.ndarray) and src_rgbs.ndim < 3:
        raise ValueError(f'src_rgbs must be a sequence of images, got an array of shape {src_rgbs.shape}')
    src_list = list(src_rgbs)
    n = len(src_list)
    cams = _cameras('src_cams', src_cams, n)
    t_ws = _poses('src_poses', src_poses, n)
    greys = [_grey(f'src_rgbs[{i}]', im, c) for i, (im, c) in enumerate(zip(src_list, cams))]
    if depth_range is not None:
        near, far = (float(v) for v in depth_range)
        if not (0 < near < far and math.isfinite(far)):
            raise ValueError(f'depth_range must be (near, far) with 0 < near < far < inf, got {depth_range}')
    elif points_w is not None:
        rng = depth_range_from_points(points_w, ref_cam, t_wr)
        if rng is None:
            return _empty(ref.shape, REASON_NO_DEPTH_RANGE)
        near, far = rng
    else:
        raise ValueError('mvs_depth needs depth_range or points_w')
    if n == 0:
        return _empty(ref.shape, REASON_NO_SOURCES, (), (near, far))
    if o.backend == 'colmap':
        views = [MvsView(np.asarray(ref_rgb), ref_cam, t_wr)]
        views += [MvsView(np.asarray(im), c, t) for im, c, t in zip(src_list, cams, t_ws)]
        r = _colmap_depth_maps(views, [list(range(1, n + 1))], (near, far), o)[0]
        return replace(r, depth=r.photometric_depth, n_consistent=np.zeros(ref.shape, np.uint8))
    # Sources that see some of the reference frustum between near and far.
    probes = np.concatenate([probe_points(ref_cam, t_wr, d, 7) for d in (near, math.sqrt(near * far), far)])
    keep = [i for i in range(n) if _in_view(probes, cams[i], t_ws[i])[0].any()]
    if not keep:
        return _empty(ref.shape, REASON_NO_OVERLAP, (), (near, far))
    out = _sweep_and_refine(
        ref, ref_cam, t_wr, [greys[i] for i in keep], [cams[i] for i in keep], t_ws[keep], near, far, o,
        sweep_window,
    )  # fmt: skip
    if isinstance(out, str):
        return _empty(ref.shape, out, keep, (near, far))
    depth, conf, n_planes = out
    zero = np.zeros(ref.shape, np.uint8)
    return MvsResult(depth, conf, zero, depth.copy(), tuple(keep), '', (near, far), n_planes)


def geometric_filter(
    depths: Sequence[ArrayLike],
    cams: PinholeCamera | Sequence[PinholeCamera],
    poses: ArrayLike,
    *,
    pairs: Sequence[Sequence[int]] | None = None,
    min_consistent: int = 2,
    max_reproj_px: float = 1.0,
    max_rel_depth_err: float = 0.01,
) -> tuple[list[NDArray[np.float32]], list[NDArray[np.uint8]]]:
    """Keep the depths that at least ``min_consistent`` other views' depth maps confirm.

    A pixel of view i at depth d goes to 3D, into view j (``pairs[i]``, default all others) where
    j's depth at that sub-pixel position (bilinear in inverse depth where the 4 pixels around are
    known, else the nearest pixel's) takes it back to 3D and into i: j agrees when it lands within
    ``max_reproj_px`` pixels of where it started with a z-depth within ``max_rel_depth_err`` x d.
    Views with fewer than ``min_consistent`` partners need all of them (at least one). Returns the
    filtered depths (0 = unknown) and the per-pixel agreeing-view counts (uint8). Depth 0, NaN or
    inf counts as unknown.
    """
    n = len(depths)
    cam_l = _cameras('cams', cams, n)
    t = _poses('poses', poses, n)
    ds = []
    for i, (d, c) in enumerate(zip(depths, cam_l)):
        a = np.asarray(d, dtype=np.float32)
        if a.shape != (c.height, c.width):
            raise ValueError(f'depths[{i}] has shape {a.shape}, its camera is {c.width}x{c.height}')
        ds.append(np.ascontiguousarray(np.where(np.isfinite(a) & (a > 0), a, 0.0), dtype=np.float32))
    if pairs is None:
        pairs = [[j for j in range(n) if j != i] for i in range(n)]
    if len(pairs) != n:
        raise ValueError(f'pairs has {len(pairs)} entries for {n} depth maps')
    out_d, out_c = [], []
    for i in range(n):
        count = np.zeros(ds[i].shape, np.uint8)
        others = sorted({int(j) for j in pairs[i]} - {i})
        for j in others:
            if not 0 <= j < n:
                raise ValueError(f'pairs[{i}] names view {j}, there are {n}')
            r_ji, t_ji = _relative(t[i], t[j])
            r_ij, t_ij = _relative(t[j], t[i])
            ki, kj = cam_l[i].k, cam_l[j].k
            _consistency(
                ds[i], ki, np.linalg.inv(ki), r_ji, t_ji, ds[j], kj, np.linalg.inv(kj), r_ij, t_ij,
                float(max_reproj_px), float(max_rel_depth_err), count,
            )  # fmt: skip
        keep = count >= max(1, min(min_consistent, len(others)))
        out_d.append(np.where(keep, ds[i], 0.0).astype(np.float32))
        out_c.append(count)
    return out_d, out_c


def compute_depth_maps(
    views: Sequence[MvsView],
    *,
    options: MvsOptions | None = None,
    points_w: ArrayLike | None = None,
    depth_range: tuple[float, float] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[MvsResult]:
    """Geometrically filtered depth maps of every view (COLMAP's "geometric" depth maps).

    Per view: neighbours by :func:`select_neighbours` (``options``' neighbour settings), depth by
    :func:`mvs_depth` (range ``depth_range``, else from the view's visible ``points_w``), then
    :func:`geometric_filter` between views that are neighbours either way. A view without
    neighbours gets an all-zero result with ``reason`` ``no_sources`` (or ``no_depth_range``).
    ``progress(done, total)`` is called after each view.
    """
    o = options or MvsOptions()
    views = list(views)
    for i, v in enumerate(views):
        if not isinstance(v, MvsView):
            raise ValueError(f'views[{i}] must be an MvsView, got {type(v).__name__}')
    n = len(views)
    if n == 0:
        return []
    if depth_range is None and points_w is None:
        raise ValueError('compute_depth_maps needs depth_range or points_w')
    points = np.empty((0, 3)) if points_w is None else points_w  # read only without a depth_range
    cams = [check_camera(f'views[{i}].camera', v.camera) for i, v in enumerate(views)]
    poses = _poses(
        'views[].t_wc', np.stack([np.asarray(v.t_wc, dtype=np.float64).reshape(4, 4) for v in views])
    )
    for i, (v, c) in enumerate(zip(views, cams)):
        _grey(f'views[{i}].rgb', v.rgb, c)
    kw = o.neighbour_options()
    nbrs: list[list[int]] = []
    no_range = [False] * n
    for i in range(n):
        if depth_range is None and depth_range_from_points(points, cams[i], poses[i]) is None:
            no_range[i] = True
            nbrs.append([])
        else:
            nbrs.append(select_neighbours(i, poses, cams, points_w=points_w, depth_range=depth_range, **kw))
    if o.backend == 'colmap':
        rng = depth_range
        if rng is None:
            ranges = [depth_range_from_points(points, c, p) for c, p in zip(cams, poses)]
            found = [r for r in ranges if r is not None]
            if not found:
                raise ValueError('points_w: no view sees 10 or more of them, pass depth_range')
            rng = (min(r[0] for r in found), max(r[1] for r in found))
        return _colmap_depth_maps(views, nbrs, rng, o)
    results: list[MvsResult] = []
    for i, v in enumerate(views):
        if not nbrs[i]:
            reason = REASON_NO_DEPTH_RANGE if no_range[i] else REASON_NO_SOURCES
            results.append(_empty((cams[i].height, cams[i].width), reason))
        else:
            js = nbrs[i]
            r = mvs_depth(
                v.rgb, cams[i], poses[i], [views[j].rgb for j in js], [cams[j] for j in js], poses[js],
                depth_range=depth_range, points_w=points_w, options=o,
            )  # fmt: skip
            results.append(replace(r, neighbours=tuple(js[k] for k in r.neighbours)))
        if progress is not None:
            progress(i + 1, n)
    pairs = [
        sorted(set(results[i].neighbours) | {j for j in range(n) if i in results[j].neighbours})
        for i in range(n)
    ]
    filt, counts = geometric_filter(
        [r.photometric_depth for r in results], cams, poses, pairs=pairs,
        min_consistent=o.min_consistent, max_reproj_px=o.max_reproj_px, max_rel_depth_err=o.max_rel_depth_err,
    )  # fmt: skip
    return [
        replace(r, depth=d, confidence=np.where(d > 0, r.confidence, 0.0).astype(np.float32), n_consistent=c)
        for r, d, c in zip(results, filt, counts)
    ]


# --------------------------------------------------------------------------------------------- COLMAP


def _read_colmap_array(path: Path) -> NDArray[np.float32]:
    """A COLMAP dense ``.bin`` array ("width&height&channels&" then float32 data) as HxW or HxWxC."""
    data = path.read_bytes()
    end = 0
    for _ in range(3):
        end = data.index(b'&', end) + 1
    w, h, c = (int(v) for v in data[: end - 1].split(b'&'))
    arr = np.frombuffer(data, np.float32, count=w * h * c, offset=end).reshape(c, h, w).transpose(1, 2, 0)
    return arr[..., 0].copy() if c == 1 else arr.copy()


def _colmap_depth_maps(
    views: Sequence[MvsView], nbrs: Sequence[Sequence[int]], depth_range: tuple[float, float], o: MvsOptions
) -> list[MvsResult]:
    """Depth maps from ``pycolmap.patch_match_stereo`` (CUDA builds only) on a temporary workspace.

    The workspace holds the images (PNG), a sparse model with the known PINHOLE cameras and poses
    (COLMAP's pixel centres are at +0.5) and ``patch-match.cfg`` naming each view's neighbours.
    ``photometric_depth`` is COLMAP's photometric map, ``depth`` its geometric one; COLMAP does not
    report per-pixel consistency counts, so ``n_consistent`` is ``min_consistent`` where kept.
    """
    from ibr_ros.core.registration.colmap import pycolmap as _import_pycolmap

    pycolmap = _import_pycolmap()
    if not getattr(pycolmap, 'has_cuda', False):
        raise MvsBackendUnavailable(
            "MVS backend 'colmap' runs pycolmap.patch_match_stereo, which needs CUDA: "
            "pycolmap was built without CUDA; use backend='cpu'"
        )
    with tempfile.TemporaryDirectory(prefix='ibr_mvs_') as tmp:
        ws = Path(tmp)
        for sub in (
            'images',
            'sparse',
            'stereo/depth_maps',
            'stereo/normal_maps',
            'stereo/consistency_graphs',
        ):
            (ws / sub).mkdir(parents=True)
        rec = pycolmap.Reconstruction()
        names = [f'{i:05d}.png' for i in range(len(views))]
        for i, v in enumerate(views):
            c = v.camera
            rec.add_camera_with_trivial_rig(
                pycolmap.Camera(
                    model='PINHOLE', width=c.width, height=c.height, camera_id=i + 1,
                    params=[c.fx, c.fy, c.cx + 0.5, c.cy + 0.5],
                )
            )  # fmt: skip
            rgb = np.asarray(v.rgb)
            cv2.imwrite(str(ws / 'images' / names[i]), rgb[..., ::-1] if rgb.ndim == 3 else rgb)
            t_cw = np.linalg.inv(np.asarray(v.t_wc, dtype=np.float64))
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(t_cw[:3, :3]), t_cw[:3, 3])
            rec.add_image_with_trivial_frame(
                pycolmap.Image(name=names[i], camera_id=i + 1, image_id=i + 1), pose
            )
        rec.write(str(ws / 'sparse'))
        lines = []
        for i, js in enumerate(nbrs):
            if js:
                lines += [names[i], ', '.join(names[j] for j in js)]
        (ws / 'stereo' / 'patch-match.cfg').write_text('\n'.join(lines) + '\n')
        pm = pycolmap.PatchMatchOptions()
        pm.depth_min, pm.depth_max = float(depth_range[0]), float(depth_range[1])
        pm.geom_consistency = True
        pm.filter = True
        pm.filter_min_num_consistent = o.min_consistent
        pm.filter_geom_consistency_max_cost = o.max_reproj_px
        pycolmap.patch_match_stereo(ws, workspace_format='COLMAP', options=pm)
        out = []
        for i, v in enumerate(views):
            shape = (v.camera.height, v.camera.width)
            maps = []
            for kind in ('geometric', 'photometric'):
                f = ws / 'stereo' / 'depth_maps' / f'{names[i]}.{kind}.bin'
                a = (
                    np.nan_to_num(_read_colmap_array(f), nan=0.0)
                    if f.exists()
                    else np.zeros(shape, np.float32)
                )
                maps.append(np.where(a > 0, a, 0.0).astype(np.float32))
            geo, pho = maps
            reason = '' if nbrs[i] else REASON_NO_SOURCES
            kept = (geo > 0).astype(np.uint8) * np.uint8(min(o.min_consistent, 255))
            out.append(
                MvsResult(geo, np.zeros(shape, np.float32), kept, pho, tuple(nbrs[i]), reason, depth_range)
            )
        return out
