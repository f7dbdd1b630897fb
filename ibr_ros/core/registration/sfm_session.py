# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Incremental registration of pose-less keyframes (SfM mode): :class:`SfmSession`.

Views (RGB uint8, a :class:`PinholeCamera` from their CameraInfo, a stamp in ns, optionally a GPS
position in ENU metres) are accumulated with :meth:`SfmSession.add`; every :meth:`SfmSession.update`
re-runs :func:`~ibr_ros.core.registration.sfm.register_images` over all of them (one shared camera, the first
view's intrinsics as the prior) and returns a ``T_wc`` (4x4 camera-to-world, REP-103 optical
frame) or None (not registered) per stamp.

World frame of the results (``SfmUpdate.frame``), fixed by the first accepted update:

* ``'enu'``: when :func:`register_images` could align the model to the GPS positions (>= 3
  registered views with GPS, not collinear): ENU metres, the origin of the given positions.
* ``'sfm'``: otherwise. z is up: the normal of the dominant plane of the sparse points (the
  ground), on the side of the cameras (the mean image-up direction of the cameras when no plane
  is found or it disagrees with it by more than 60 deg); x is the first registered view's optical
  axis projected on that plane (its image-up direction for a nadir view), y = z x x; the origin is
  the first registered view's centre projected on the plane, so the ground is near z = 0. The
  unit is the distance between the first two registered views (by stamp) unless ``scale_hint``
  says how many metres that distance (``baseline``), the first view's height above the plane
  (``altitude``) or the median depth of the sparse points (``depth``) is; then it is metres, as
  accurate as the hint.

Later updates are expressed in the frame of the previous one: a similarity fitted to the common
registered camera centres (:func:`~ibr_ros.core.registration.sfm.robust_similarity`; for collinear centres the
rotation is averaged from the camera orientations instead), so already-published poses and depths
keep one frame and scale. A common view counts as consistent when its centre moved by less than
``inlier_ratio`` x the median spacing of the common centres and its orientation by less than
``max_rotation_deg``; when fewer than 2 (or fewer than half) are consistent the new model is
rejected (the previous poses stay), unless it registers at least twice as many views and
``redefine`` is set, which redefines the frame (``reset``). The one other reset: an ``'sfm'``
session whose model becomes GPS-aligned switches to ``'enu'``. After a reset every earlier pose
and depth is superseded.

Cost: each update re-extracts and re-matches all views (exhaustive matching up to
``SfmOptions.exhaustive_max_images``); ``max_side`` downscales the images for SfM only.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Literal, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.plane import fit_ground_plane
from ibr_ros.core.geometry.transforms import matrix_from_rt, rotation_angle_deg, similarity_times_pose
from ibr_ros.core.registration.sfm import (
    SfmError,
    SfmOptions,
    SfmResult,
    register_images,
    robust_similarity,
    similarity_from_orientations,
)

__all__ = ['Frame', 'ScaleHint', 'SfmSession', 'SfmUpdate']

LOG = logging.getLogger(__name__)

Frame = Literal['enu', 'sfm']
ScaleKind = Literal['baseline', 'altitude', 'depth']
_SCALE_KINDS = ('baseline', 'altitude', 'depth')


@dataclass(frozen=True)
class ScaleHint:
    """A known length (metres) that fixes the scale of the ``'sfm'`` frame (see the module docstring)."""

    kind: ScaleKind
    metres: float

    def __post_init__(self) -> None:
        if self.kind not in _SCALE_KINDS:
            raise ValueError(f'ScaleHint.kind must be one of {list(_SCALE_KINDS)}, got {self.kind!r}')
        if not (math.isfinite(self.metres) and self.metres > 0):
            raise ValueError(f'ScaleHint.metres must be finite and > 0, got {self.metres}')


@dataclass(frozen=True, eq=False)
class SfmUpdate:
    """Outcome of :meth:`SfmSession.update` (world frame and units: see the module docstring).

    ``poses``: every view added so far, by stamp: 4x4 ``T_wc`` or None (not registered).
    ``accepted``: the new reconstruction was adopted (else ``poses`` are the previous ones and
    ``reason`` says why). ``reset``: the frame was (re)defined by this update, earlier poses are
    superseded. ``new``: stamps registered now that had no pose before (all registered ones after
    a reset). ``frame_rms``: RMS distance (world units) between the previous and the new centres of
    the consistent common views (NaN after a reset or when not accepted). ``points``: Px3 sparse
    points in the world frame. ``camera``: the refined shared camera at the input resolution.
    ``metric``: the unit is metres (ENU or a scale hint). ``seconds``: wall time of the update.
    """

    poses: dict[int, NDArray[np.float64] | None]
    frame: Frame | None
    accepted: bool
    reset: bool
    reason: str
    new: tuple[int, ...]
    frame_rms: float
    points: NDArray[np.float64]
    camera: PinholeCamera | None
    metric: bool
    seconds: float
    result: SfmResult | None = None
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def num_views(self) -> int:
        return len(self.poses)

    @property
    def num_registered(self) -> int:
        return sum(p is not None for p in self.poses.values())

    def observed_points(
        self, stamps: list[int], *, min_track: int = 3, max_error_px: float = 2.0
    ) -> dict[int, NDArray[np.float64]]:
        """World points (Kx3, ``points``' frame) each registered view observed itself, by stamp:
        those seen by at least ``min_track`` views with a mean reprojection error up to
        ``max_error_px`` (reliable depth samples of that view). ``stamps``: the session's, sorted
        (the order of the reconstruction's images)."""
        res = self.result
        out: dict[int, NDArray[np.float64]] = {}
        if res is None or not self.accepted:
            return out
        good = (res.track_lengths >= min_track) & (res.point_errors <= max_error_px)
        for i, stamp in enumerate(stamps):
            if self.poses.get(stamp) is None or i >= len(res.observation_ids):
                continue
            ids = np.unique(res.observation_ids[i])
            out[stamp] = self.points[ids[good[ids]]]
        return out


@dataclass
class _View:
    rgb: NDArray[np.uint8]
    gps: NDArray[np.float64]


class SfmSession:
    """Accumulates pose-less views and registers them incrementally (see the module docstring).

    ``options``: passed to :func:`register_images` (default: ``SfmOptions(num_threads=2)``);
    ``max_side``: longest image side (px) used for SfM, larger views are downscaled (0 = as given);
    ``min_registered``: views the first reconstruction must register to be accepted;
    ``inlier_ratio``, ``max_rotation_deg``, ``redefine``: the alignment to the previous frame.
    """

    def __init__(
        self,
        *,
        options: SfmOptions | None = None,
        scale_hint: ScaleHint | None = None,
        max_side: int = 0,
        min_registered: int = 3,
        inlier_ratio: float = 0.1,
        max_rotation_deg: float = 2.0,
        redefine: bool = True,
    ) -> None:
        if max_side < 0 or min_registered < 2 or inlier_ratio <= 0 or max_rotation_deg <= 0:
            raise ValueError(
                f'need max_side >= 0, min_registered >= 2, inlier_ratio > 0 and max_rotation_deg > 0, got '
                f'{max_side}, {min_registered}, {inlier_ratio}, {max_rotation_deg}'
            )
        self.options = options or SfmOptions(num_threads=2)
        self.scale_hint = scale_hint
        self.max_side = int(max_side)
        self.min_registered = int(min_registered)
        self.inlier_ratio = float(inlier_ratio)
        self.max_rotation_deg = float(max_rotation_deg)
        self.redefine = bool(redefine)
        self._views: dict[int, _View] = {}
        self._camera: PinholeCamera | None = None  # the prior, at the input resolution
        self._scale = 1.0  # SfM image size / input image size
        self._poses: dict[int, NDArray[np.float64]] = {}
        self._frame: Frame | None = None
        self.generation = 0  # incremented by every reset

    # -- input ------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._views)

    def __contains__(self, stamp: object) -> bool:
        return stamp in self._views

    @property
    def frame(self) -> Frame | None:
        """The world frame of the poses (None before the first accepted update)."""
        return self._frame

    @property
    def stamps(self) -> list[int]:
        return sorted(self._views)

    def pose(self, stamp: int) -> NDArray[np.float64] | None:
        """The latest ``T_wc`` of the view ``stamp`` (a copy), None if it is not registered."""
        p = self._poses.get(int(stamp))
        return None if p is None else p.copy()

    def add(
        self,
        stamp_ns: int,
        rgb: NDArray[np.uint8],
        camera: PinholeCamera,
        gps_enu: NDArray[np.float64] | None = None,
    ) -> None:
        """Add one view: ``rgb`` HxWx3 uint8, ``camera`` of that size, ``gps_enu`` (3,) ENU metres or None.

        Raises:
            SfmError: A repeated stamp, a bad image, a camera that does not fit the image or
                another size than the first view's, or a GPS position that is not 3 finite numbers.

        """
        stamp = int(stamp_ns)
        if stamp in self._views:
            raise SfmError(f'stamp {stamp} ns was already added')
        a = np.asarray(rgb)
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
            raise SfmError(f'rgb of stamp {stamp} ns must be HxWx3 uint8, got {a.dtype} {a.shape}')
        if (camera.height, camera.width) != a.shape[:2]:
            raise SfmError(
                f'camera of stamp {stamp} ns is {camera.width}x{camera.height} but its image is '
                f'{a.shape[1]}x{a.shape[0]}'
            )
        if self._camera is not None and (camera.width, camera.height) != (
            self._camera.width,
            self._camera.height,
        ):
            raise SfmError(
                f'camera of stamp {stamp} ns is {camera.width}x{camera.height}, the session '
                f'registers one camera of {self._camera.width}x{self._camera.height}'
            )
        gps = np.full(3, np.nan)
        if gps_enu is not None:
            g = np.asarray(gps_enu, dtype=np.float64)
            if g.shape != (3,) or not np.all(np.isfinite(g)):
                raise SfmError(f'gps_enu of stamp {stamp} ns must be 3 finite numbers, got {g.tolist()}')
            gps = g.copy()
        if self._camera is None:
            self._camera = camera
            side = max(camera.width, camera.height)
            self._scale = self.max_side / side if 0 < self.max_side < side else 1.0
        if self._scale != 1.0:
            w, h = round(a.shape[1] * self._scale), round(a.shape[0] * self._scale)
            a = cast('NDArray[np.uint8]', cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA))  # keeps uint8
        self._views[stamp] = _View(np.ascontiguousarray(a), gps)

    # -- registration -----------------------------------------------------------------------------
    def update(self) -> SfmUpdate:
        """Register all views again and express them in the session's frame (module docstring).

        Never raises for a failed reconstruction: ``accepted`` is False and ``reason`` says why.
        """
        t0 = time.perf_counter()
        stamps = self.stamps
        if len(stamps) < 2:
            return self._unchanged(f'{len(stamps)} views: registration needs at least 2', t0)
        gps = np.array([self._views[s].gps for s in stamps])
        has_gps = bool(np.isfinite(gps[:, 0]).any())
        cam = self._camera
        assert cam is not None
        prior = cam if self._scale == 1.0 else cam.scaled(self._scale)
        prior_images = [self._views[s].rgb for s in stamps]
        if (prior.width, prior.height) != prior_images[0].shape[1::-1]:  # rounding of the scaled size
            prior = cam.scaled(prior_images[0].shape[1] / cam.width, prior_images[0].shape[0] / cam.height)
        try:
            res = register_images(
                prior_images, camera=prior, gps_enu=gps if has_gps else None, options=self.options
            )
        except SfmError as exc:
            return self._unchanged(f'SfM failed: {exc}', t0)
        camera = res.camera
        if self._scale != 1.0:
            camera = camera.scaled(cam.width / camera.width, cam.height / camera.height)
        new = {s: res.poses[i] for i, s in enumerate(stamps) if res.registered[i]}
        if self._frame is None and len(new) < self.min_registered:
            return self._unchanged(
                f'only {len(new)} of {len(stamps)} views registered (need {self.min_registered})', t0, res
            )
        reset, rms, reason = False, math.nan, 'ok'
        frame: Frame | None
        if self._frame is None or (self._frame == 'sfm' and res.metric):
            m, frame, reset = self._define_frame(res), 'enu' if res.metric else 'sfm', True
            reason = 'frame defined'
        else:
            frame = self._frame
            fit, why = self._fit_to_previous(new)
            if fit is not None:
                m, rms = fit
            elif self.redefine and len(new) >= 2 * len(self._poses):
                m, frame, reset = self._define_frame(res), 'enu' if res.metric else 'sfm', True
                reason = f'frame redefined ({why}; the new model registers {len(new)} views)'
                LOG.warning('SfM session: %s', reason)
            else:
                return self._unchanged(f'new model rejected: {why}', t0, res)
        before = set() if reset else set(self._poses)
        self._poses = {s: similarity_times_pose(m, p) for s, p in new.items()}
        self._frame = frame
        if reset:
            self.generation += 1
        points = res.points @ m[:3, :3].T + m[:3, 3] if len(res.points) else np.zeros((0, 3))
        return SfmUpdate(
            poses=self._all_poses(),
            frame=frame,
            accepted=True,
            reset=reset,
            reason=reason,
            new=tuple(s for s in sorted(self._poses) if s not in before),
            frame_rms=rms,
            points=points,
            camera=camera,
            metric=self.metric,
            seconds=time.perf_counter() - t0,
            result=res,
            timing=dict(res.timing),
        )

    @property
    def metric(self) -> bool:
        """Whether the world unit is the metre (ENU frame, or a scale hint)."""
        return self._frame == 'enu' or (self._frame == 'sfm' and self.scale_hint is not None)

    def _all_poses(self) -> dict[int, NDArray[np.float64] | None]:
        return {s: (self._poses[s].copy() if s in self._poses else None) for s in self.stamps}

    def _unchanged(self, reason: str, t0: float, res: SfmResult | None = None) -> SfmUpdate:
        LOG.info('SfM session: %s', reason)
        return SfmUpdate(
            poses=self._all_poses(),
            frame=self._frame,
            accepted=False,
            reset=False,
            reason=reason,
            new=(),
            frame_rms=math.nan,
            points=np.zeros((0, 3)),
            camera=None,
            metric=self.metric,
            seconds=time.perf_counter() - t0,
            result=res,
            timing=dict(res.timing) if res is not None else {},
        )

    def _define_frame(self, res: SfmResult) -> NDArray[np.float64]:
        """Similarity from the model's frame to the session's world frame (identity for ENU)."""
        if res.metric:
            return np.eye(4)
        reg = np.flatnonzero(res.registered)
        poses = res.poses[reg]
        c0 = poses[0, :3, 3]
        cam_up = -poses[:, :3, 1].mean(axis=0)  # mean image-up direction
        up = None
        try:
            n_d = fit_ground_plane(res.points) if len(res.points) >= 10 else None
        except ValueError:
            n_d = None
        if n_d is not None:
            n, d = n_d[:3], float(n_d[3])
            side = poses[:, :3, 3] @ n + d
            if np.mean(side < 0) > 0.5:
                n, d = -n, -d
            agree = np.linalg.norm(cam_up) < 0.5 or n @ cam_up > 0.5 * np.linalg.norm(cam_up)
            if agree:
                up = n
        if up is None:
            if np.linalg.norm(cam_up) < 1e-6:
                cam_up = -poses[0, :3, 1]
            up = cam_up / np.linalg.norm(cam_up)
            d = -float(up @ np.median(res.points, axis=0)) if len(res.points) else -float(up @ c0) + 1.0
            LOG.warning(
                'SfM frame: no ground plane consistent with the cameras; up = mean image-up direction'
            )
        heading = poses[0, :3, 2] - (poses[0, :3, 2] @ up) * up
        if np.linalg.norm(heading) < 0.2:  # nadir: the image-up direction instead
            img_up = -poses[0, :3, 1]
            heading = img_up - (img_up @ up) * up
        x = heading / np.linalg.norm(heading)
        y = np.cross(up, x)
        r = np.stack([x, y, up])  # rows: world axes in SfM coordinates
        height = float(up @ c0 + d)
        origin = c0 - height * up
        k = 1.0
        baseline = float(np.linalg.norm(poses[1, :3, 3] - c0)) if len(reg) > 1 else 0.0
        hint = self.scale_hint
        if hint is None or hint.kind == 'baseline':
            size = baseline
        elif hint.kind == 'altitude':
            size = height
        else:
            z = np.concatenate([o[:, 2] for o in res.observations if len(o)] or [np.zeros(0)])
            size = float(np.median(z)) if len(z) else 0.0
        target = hint.metres if hint is not None else 1.0
        if size > 1e-9:
            k = target / size
        else:
            LOG.warning(
                'SfM frame: scale reference %s is %.3g: SfM scale kept',
                hint.kind if hint else 'baseline',
                size,
            )
        return matrix_from_rt(k * r, -k * r @ origin)

    def _fit_to_previous(
        self, new: dict[int, NDArray[np.float64]]
    ) -> tuple[tuple[NDArray[np.float64], float] | None, str]:
        """Similarity from the new model to the session's frame over the common views, and its RMS."""
        common = sorted(set(new) & set(self._poses))
        if len(common) < 2:
            return None, f'{len(common)} registered views in common with the previous model (need 2)'
        src = np.array([new[s][:3, 3] for s in common])
        dst = np.array([self._poses[s][:3, 3] for s in common])
        r_src = np.array([new[s][:3, :3] for s in common])
        r_dst = np.array([self._poses[s][:3, :3] for s in common])
        gaps = np.linalg.norm(dst[:, None] - dst[None], axis=2) + np.diag(np.full(len(dst), np.inf))
        thr = self.inlier_ratio * float(np.median(gaps.min(axis=1)))
        if thr <= 0:
            return None, 'the common views have coincident centres'
        need = max(2, math.ceil(0.5 * len(common)))

        def check(m: NDArray[np.float64]) -> NDArray[np.bool_]:
            s = float(np.cbrt(np.linalg.det(m[:3, :3])))
            res = np.linalg.norm(src @ m[:3, :3].T + m[:3, 3] - dst, axis=1)
            rot = np.array([rotation_angle_deg(m[:3, :3] / s @ a, b) for a, b in zip(r_src, r_dst)])
            return (res < thr) & (rot < self.max_rotation_deg)

        def by_orientation(inl: NDArray[np.bool_]) -> NDArray[np.float64] | None:
            return similarity_from_orientations(src[inl], dst[inl], r_src[inl], r_dst[inl])

        candidates = [by_orientation(np.ones(len(common), bool))]
        if len(common) >= 3:
            fit = robust_similarity(src, dst, inlier_m=thr, iterations=200, seed=0)
            candidates.append(None if fit is None else fit[0])
        best, best_inl = None, np.zeros(len(common), bool)
        for m in candidates:
            inl = check(m) if m is not None else best_inl
            if inl.sum() > best_inl.sum():
                best, best_inl = m, inl
        if best is None or best_inl.sum() < need:
            return None, (
                f'{int(best_inl.sum())} of {len(common)} common views consistent (need {need}; '
                f'centre within {thr:.3g}, rotation within {self.max_rotation_deg:g} deg)'
            )
        # Camera orientations are far better determined than a rotation from (near-collinear) centres.
        final = by_orientation(best_inl)
        if final is not None and (final_inl := check(final)).sum() >= best_inl.sum():
            best, best_inl = final, final_inl
        res = np.linalg.norm(src @ best[:3, :3].T + best[:3, 3] - dst, axis=1)[best_inl]
        return (best, float(np.sqrt(np.mean(res**2)))), 'ok'
