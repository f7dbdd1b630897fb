# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Register the camera images of a bag with SfM (:func:`ibr_ros.core.registration.sfm.register_images`).

Reads the image topic (``sensor_msgs/Image`` or ``CompressedImage``), the first ``CameraInfo`` as
the initial intrinsics, and ``NavSatFix`` positions. GPS is converted to ENU metres with the first
usable fix as origin (:mod:`ibr_ros.core.geometry.geodesy`) and interpolated linearly to each image's header
stamp; images further than ``max_gps_gap_s`` from a fix get NaN (unknown). Fixes with
``status < 0`` (no fix) or without altitude are ignored.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import msg_utils
from ibr_ros.bag import TopicSelection, detect_topics, open_bag
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.geodesy import geodetic_to_enu
from ibr_ros.core.registration.sfm import SfmOptions, SfmResult, register_images
from ibr_ros.errors import BagError

__all__ = [
    'BagRegistration',
    'fixes_to_enu',
    'interpolate_positions',
    'register_bag',
    'registration_to_dict',
    'select_indices',
]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class BagRegistration:
    """SfM result of a bag's images with their header stamps (ns) and the ENU origin.

    ``origin`` is the (lat deg, lon deg, ellipsoidal alt m) of ENU (0, 0, 0), None without GPS;
    ``gps_enu`` the Nx3 GPS positions given to SfM (NaN = unknown), None without GPS;
    ``indices`` the positions of the used images among all images of the topic.
    """

    result: SfmResult
    stamps_ns: NDArray[np.int64]
    indices: NDArray[np.int64]
    origin: tuple[float, float, float] | None
    gps_enu: NDArray[np.float64] | None
    topics: TopicSelection


def select_indices(count: int, max_images: int | None) -> NDArray[np.int64]:
    """``max_images`` indices evenly spread over ``range(count)`` (first and last kept); all if None."""
    if max_images is None or max_images >= count:
        return np.arange(count, dtype=np.int64)
    if max_images < 2:
        raise ValueError(f'max_images must be >= 2, got {max_images}')
    return np.unique(np.round(np.linspace(0, count - 1, max_images)).astype(np.int64))


def interpolate_positions(
    stamps: NDArray[np.int64], fix_t: NDArray[np.int64], fix_p: NDArray, gap_s: float
) -> NDArray:
    """Nx3 positions at ``stamps`` (ns), linear between fixes at most ``gap_s`` (s) away; NaN elsewhere."""
    out = np.full((len(stamps), 3), np.nan)
    if len(fix_t) == 0:
        return out
    gap_ns = gap_s * 1e9
    for i, t in enumerate(stamps):
        j = int(np.searchsorted(fix_t, t))
        lo, hi = max(j - 1, 0), min(j, len(fix_t) - 1)
        if fix_t[hi] == t or lo == hi:
            k = hi if abs(fix_t[hi] - t) <= abs(fix_t[lo] - t) else lo
            if abs(int(fix_t[k]) - int(t)) <= gap_ns:
                out[i] = fix_p[k]
        elif t - fix_t[lo] <= gap_ns and fix_t[hi] - t <= gap_ns:
            a = (t - fix_t[lo]) / (fix_t[hi] - fix_t[lo])
            out[i] = (1 - a) * fix_p[lo] + a * fix_p[hi]
    return out


def _fit_camera(camera: PinholeCamera | None, width: int, height: int) -> PinholeCamera | None:
    if camera is None or (camera.width, camera.height) == (width, height):
        return camera
    sx, sy = width / camera.width, height / camera.height
    if abs(sx / sy - 1.0) < 0.01:
        return camera.scaled(sx, sy)
    LOG.warning(
        'CameraInfo is %dx%d but the images are %dx%d: not used as initial intrinsics',
        camera.width,
        camera.height,
        width,
        height,
    )
    return None


def fixes_to_enu(
    fixes: list[msg_utils.GeoFix], stamps_ns: NDArray[np.int64], max_gap_s: float = 2.0
) -> tuple[NDArray[np.float64] | None, tuple[float, float, float] | None]:
    """ENU metres (Nx3, NaN unknown) at ``stamps_ns`` from GPS ``fixes``, and the ENU origin.

    The origin is the first fix in time (latitude, longitude in degrees, altitude in metres);
    positions are interpolated linearly in time (:func:`interpolate_positions`). ``(None, None)``
    without fixes. Callers filter fixes without a fix or an altitude.
    """
    if not fixes:
        return None, None
    fixes = sorted(fixes, key=lambda f: f.stamp_ns)
    origin = (fixes[0].latitude_deg, fixes[0].longitude_deg, fixes[0].altitude_m)
    lat, lon, alt = (
        np.array([getattr(f, k) for f in fixes]) for k in ('latitude_deg', 'longitude_deg', 'altitude_m')
    )
    enu = np.stack(geodetic_to_enu(lat, lon, alt, origin), axis=1)
    fix_t = np.array([f.stamp_ns for f in fixes], dtype=np.int64)
    return interpolate_positions(np.asarray(stamps_ns, dtype=np.int64), fix_t, enu, max_gap_s), origin


def register_bag(
    path: Path | str,
    *,
    max_images: int | None = None,
    image_topic: str | None = None,
    use_gps: bool = True,
    max_gps_gap_s: float = 2.0,
    options: SfmOptions | None = None,
    workdir: Path | None = None,
) -> BagRegistration:
    """Register up to ``max_images`` images (evenly spread over the bag) of ``path``.

    Raises:
        BagError: No image topic, or the bag cannot be read.
        SfmError: Registration failed (see :func:`ibr_ros.core.registration.sfm.register_images`).

    """
    with open_bag(path) as reader:
        topics = detect_topics(reader, image=image_topic)
        if topics.image is None:
            raise BagError(path, 'no camera image topic (sensor_msgs/Image or CompressedImage)')
        indices = select_indices(reader.topics[topics.image].count, max_images)
        wanted = set(indices.tolist())
        images: list[np.ndarray] = []
        stamps: list[int] = []
        camera: PinholeCamera | None = None
        fixes: list[msg_utils.GeoFix] = []
        names = [t for t in (topics.image, topics.camera_info, topics.navsat if use_gps else None) if t]
        n_seen = 0
        for m in reader.messages(names):
            if m.topic == topics.image:
                if n_seen in wanted:
                    msg: Any = m.msg
                    images.append(msg_utils.camera_image_to_rgb(msg))
                    stamps.append(msg_utils.stamp_to_ns(msg.header.stamp))
                n_seen += 1
            elif m.topic == topics.camera_info and camera is None:
                camera = msg_utils.camera_info_to_pinhole(m.msg)
            elif m.topic == topics.navsat:
                fix = msg_utils.navsatfix_to_fix(m.msg)
                if fix.status >= 0 and np.isfinite(fix.altitude_m):
                    fixes.append(fix)
    if not images:
        raise BagError(path, f'no messages on {topics.image}')
    stamps_ns = np.array(stamps, dtype=np.int64)
    h, w = images[0].shape[:2]
    gps, origin = fixes_to_enu(fixes, stamps_ns, max_gps_gap_s)
    if gps is not None:
        LOG.info('%d of %d images have a GPS position', int(np.isfinite(gps[:, 0]).sum()), len(images))
    result = register_images(
        images, camera=_fit_camera(camera, w, h), gps_enu=gps, workdir=workdir, options=options
    )
    return BagRegistration(result, stamps_ns, indices, origin, gps, topics)


def _finite_or_none(a: np.ndarray) -> list | None:
    return a.tolist() if np.all(np.isfinite(a)) else None


def registration_to_dict(reg: BagRegistration) -> dict[str, object]:
    """JSON-friendly document: :meth:`SfmResult.summary`, ENU origin and per-image pose and GPS.

    Per image: ``index`` (among the topic's images), ``stamp_ns``, ``registered``, ``t_wc``
    (4x4 camera-to-world, None if not registered), ``gps_enu`` (m, None if unknown) and
    ``num_points`` (observed 3D points).
    """
    res = reg.result
    images = []
    for i, (index, stamp) in enumerate(zip(reg.indices.tolist(), reg.stamps_ns.tolist())):
        images.append(
            {
                'index': index,
                'stamp_ns': stamp,
                'registered': bool(res.registered[i]),
                't_wc': _finite_or_none(res.poses[i]),
                'gps_enu': None if reg.gps_enu is None else _finite_or_none(reg.gps_enu[i]),
                'num_points': len(res.observations[i]),
            }
        )
    return {
        **res.summary(),
        'image_topic': reg.topics.image,
        'enu_origin': None if reg.origin is None else list(reg.origin),
        'frame': 'ENU metres (map)' if res.metric else 'arbitrary SfM frame and scale',
        'per_image': images,
    }
