# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""SfM mode: all keyframes registered together by one SfM session (with GPS when the bag has it)."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.undistort import undistort_image
from ibr_ros.core.registration.sfm import SfmError, SfmOptions
from ibr_ros.core.registration.sfm_session import SfmSession, SfmUpdate
from ibr_ros.errors import UserError
from ibr_ros.jobs.process.frames import Keyframe, Subsampled
from ibr_ros.jobs.process.options import Progress
from ibr_ros.jobs.process.params import ProcessConfigs
from ibr_ros.jobs.register_bag import fixes_to_enu

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules


#: GPS positions are interpolated to keyframe stamps at most this far from a fix (s; ``ibr register``'s).
GPS_MAX_GAP_S = 2.0


def _camera_dict(cam: PinholeCamera) -> dict[str, object]:
    return {'width': cam.width, 'height': cam.height, 'fx': cam.fx, 'fy': cam.fy, 'cx': cam.cx, 'cy': cam.cy,
            'd': cam.d.tolist(), 'distortion_model': cam.distortion_model}  # fmt: skip


@dataclass(frozen=True, eq=False)
class SparsePoints:
    """SfM's sparse points: ``points`` Px3 (the poses' frame) and, by stamp, the reliable points
    each keyframe observed itself (:meth:`SfmUpdate.observed_points`)."""

    points: NDArray[np.float64]
    observed: dict[int, NDArray[np.float64]]


def _sparse_depth(u: SfmUpdate, stamps: list[int]) -> float | None:
    """Median over the registered views of the median depth (world units) of the points each observes."""
    res = u.result
    per_view = []
    for i, s in enumerate(stamps):
        t_wc = u.poses.get(s)
        if res is None or t_wc is None or i >= len(res.observation_ids) or not len(res.observation_ids[i]):
            continue
        z = (u.points[res.observation_ids[i]] - t_wc[:3, 3]) @ t_wc[:3, 2]
        if (z := z[z > 0]).size:
            per_view.append(float(np.median(z)))
    return float(np.median(per_view)) if per_view else None


def register_keyframes(
    sub: Subsampled, cfg: ProcessConfigs, threads: int | None, progress: Progress | None
) -> tuple[list[Keyframe], ProcessConfigs, dict[str, object], SparsePoints]:
    """SfM mode: register all keyframes with ONE :meth:`SfmSession.update`; the registered keyframes
    (undistorted, with SfM's camera and pose), the configurations to refine them with, the stats and
    the sparse points (they bound each keyframe's depth range and seed its depth).
    """
    keyframes, n = sub.keyframes, len(sub.keyframes)
    if n < cfg.sfm.min_keyframes:
        raise UserError(
            f'SfM mode ({sub.sfm_why}): {n} keyframes, the depth_refiner registers at least '
            f'sfm_min_keyframes = {cfg.sfm.min_keyframes} (a longer bag, a smaller poseless_interval_s or a '
            'larger --max-keyframes)'
        )
    t0 = time.perf_counter()
    prior = keyframes[0].camera  # the bag's CameraInfo: SfM's initial intrinsics
    gps, origin = fixes_to_enu(sub.fixes, np.array([k.stamp for k in keyframes], np.int64), GPS_MAX_GAP_S)
    session = SfmSession(
        options=SfmOptions(num_threads=threads) if threads is not None else None,
        scale_hint=cfg.sfm.scale,
        max_side=cfg.sfm.max_side,
        redefine=False,
    )
    dropped: dict[int, str] = {}
    for i, k in enumerate(keyframes):
        g = gps[i] if gps is not None and np.all(np.isfinite(gps[i])) else None
        try:
            session.add(k.stamp, k.rgb, k.camera, g)
        except SfmError as exc:
            dropped[k.stamp] = f'not registered: {exc}'
    if progress is not None:
        progress('sfm', 0, 1)
    u = session.update()
    if progress is not None:
        progress('sfm', 1, 1)
    if not u.accepted or u.camera is None:
        raise UserError(f'SfM mode ({sub.sfm_why}): registration of {n} keyframes failed: {u.reason}')
    frame_id = 'map' if u.frame == 'enu' else 'sfm'
    kept: list[Keyframe] = []
    for k in keyframes:
        t_wc = u.poses.get(k.stamp)
        if t_wc is None or k.stamp in dropped:
            why = dropped.setdefault(
                k.stamp, 'not registered by SfM (too few matches with the registered keyframes)'
            )
            LOG.warning('keyframe %d ns dropped: %s', k.stamp, why)
            continue
        rgb, k.camera = undistort_image(k.rgb, u.camera)
        k.rgb = np.ascontiguousarray(rgb)
        k.t_wc, k.pose_frame = t_wc, frame_id
        kept.append(k)
    if not u.metric:
        schedule = cfg.schedule
        if schedule.depth_range is not None or schedule.scene_depth_m:
            LOG.warning(
                'SfM frame without a scale (set sfm_scale): depth_range and scene_depth_m are ignored'
            )
        cfg = replace(cfg, schedule=replace(schedule, depth_range=None, scene_depth_m=0.0))
    # Better than the scheduler's guess from the optical axes or the keyframe spacing (nadir: 3-6x off).
    unset = cfg.schedule.depth_range is None and not cfg.schedule.scene_depth_m
    if (sparse_depth := _sparse_depth(u, session.stamps) if unset else None) is not None:
        cfg = replace(cfg, schedule=replace(cfg.schedule, scene_depth_m=sparse_depth))
        LOG.info('SfM mode: scene depth %.3g (median depth of the sparse points) for MVS', sparse_depth)
    res, a = u.result, (u.result.alignment if u.result is not None else None)
    unit = 'm' if u.frame == 'enu' else 'm (sfm_scale)' if u.metric else 'first keyframe baseline'
    LOG.info(
        'SfM: %d/%d keyframes registered in %.1f s (frame %s, unit %s; reprojection error %.2f px%s)',
        u.num_registered, n, u.seconds, frame_id, unit,
        res.mean_reprojection_error_px if res is not None else math.nan,
        f'; GPS alignment RMS {a.rms_m:.2f} m' if a is not None else '',
    )  # fmt: skip
    info: dict[str, object] = {
        'why': sub.sfm_why,
        'keyframe_selection': 'sharpest per poseless_interval_s window' if sub.poseless else 'by pose',
        'keyframes': n,
        'registered': len(kept),
        'dropped': {str(s): why for s, why in sorted(dropped.items())},
        'frame': u.frame,
        'frame_id': frame_id,
        'metric': u.metric,
        'unit': unit,
        'scale_hint': None
        if cfg.sfm.scale is None
        else {'kind': cfg.sfm.scale.kind, 'metres': cfg.sfm.scale.metres},
        'max_side': cfg.sfm.max_side,
        'mean_reprojection_error_px': res.mean_reprojection_error_px if res is not None else None,
        'points': len(u.points),
        'scene_depth_from_sparse_points': sparse_depth,
        'matching': res.matching if res is not None else None,
        'camera_prior': _camera_dict(prior),
        'camera': _camera_dict(u.camera),
        'gps': None
        if gps is None
        else {
            'topic': sub.topics['navsat'],
            'fixes': len(sub.fixes),
            'keyframes_with_gps': int(np.isfinite(gps[:, 0]).sum()),
            'enu_origin': list(origin) if origin is not None else None,
            'max_gap_s': GPS_MAX_GAP_S,
            'alignment_rms_m': a.rms_m if a is not None else None,
            'alignment_max_m': a.max_m if a is not None else None,
            'alignment_inliers': len(a.inliers) if a is not None else None,
        },
        'update_s': u.seconds,
        'timing_s': dict(u.timing),
        'seconds': time.perf_counter() - t0,
    }
    return kept, cfg, info, SparsePoints(u.points, u.observed_points(session.stamps))
