# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Convert a folder of photos into a ROS 2 bag (``ibr bag from-images``).

Topics written (all stamps = EXIF capture time; header stamps equal the bag log times):

* ``/camera/image_raw/compressed`` ``sensor_msgs/CompressedImage`` (JPEG, RGB, resized to
  ``max_width`` when wider), frame ``camera_optical``;
* ``/camera/camera_info`` ``sensor_msgs/CameraInfo``: the initial guess of
  :func:`ibr_ros.io.exif.initial_camera` for the written image size (refine with SfM);
* ``/gps/fix`` ``sensor_msgs/NavSatFix`` from EXIF GPS, when present (altitude: EXIF GPSAltitude,
  which DJI writes above mean sea level; covariance unknown);
* ``/camera/gimbal_attitude`` ``geometry_msgs/QuaternionStamped``: camera optical frame in ENU from
  the DJI XMP gimbal angles, when present (frame ``enu``).

A ``LICENSE``/``COPYING`` file found beside or above the photos is copied into the bag folder:
redistributing a bag made from licensed photos must carry the notice.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

import msg_utils
from ibr_ros.bag.writer import BagWriter
from ibr_ros.core.geometry.transforms import quaternion_from_rotation
from ibr_ros.errors import UserError
from ibr_ros.io.exif import PhotoMetadata, initial_camera, read_photo_metadata

__all__ = ['IMAGE_SUFFIXES', 'TOPICS', 'ImagesToBagResult', 'images_to_bag', 'list_photos']

LOG = logging.getLogger(__name__)

IMAGE_SUFFIXES = ('.jpg', '.jpeg', '.png', '.tif', '.tiff')
TOPICS = {
    'image': '/camera/image_raw/compressed',
    'camera_info': '/camera/camera_info',
    'navsat': '/gps/fix',
    'attitude': '/camera/gimbal_attitude',
}
FRAME_ID = 'camera_optical'
NO_TIME_STEP_NS = 1_000_000_000  # photos without capture time are spaced 1 s apart
LICENSE_NAMES = ('LICENSE', 'LICENSE.txt', 'LICENSE.md', 'COPYING')


@dataclass(frozen=True)
class ImagesToBagResult:
    """What was written: the bag path, photo count, and how the intrinsics were guessed."""

    path: Path
    photos: int
    with_gps: int
    with_attitude: int
    camera_source: str
    license_copied: Path | None


def list_photos(folder: Path) -> list[Path]:
    """Image files directly in ``folder`` (or ``folder/images``), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f'{folder}: not a folder of photos')
    photos = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not photos and (folder / 'images').is_dir():
        return list_photos(folder / 'images')
    if not photos:
        raise UserError(f'{folder}: no photos ({", ".join(IMAGE_SUFFIXES)}) found')
    return photos


def _capture_order(metas: list[PhotoMetadata]) -> list[tuple[int, PhotoMetadata]]:
    """Photos with strictly increasing stamps: EXIF time order, name order for ties and missing times."""
    missing = [m.path.name for m in metas if m.capture_time_ns is None]
    if missing:
        LOG.warning(
            '%d photo(s) without EXIF capture time (%s): stamped 1 s after the previous photo',
            len(missing),
            ', '.join(missing[:5]) + (' ...' if len(missing) > 5 else ''),
        )
    timed = sorted(
        (m for m in metas if m.capture_time_ns is not None), key=lambda m: (m.capture_time_ns, m.path.name)
    )
    untimed = [m for m in metas if m.capture_time_ns is None]
    out: list[tuple[int, PhotoMetadata]] = []
    last = None
    for m in timed + untimed:
        t = m.capture_time_ns if m.capture_time_ns is not None else (last or 0) + NO_TIME_STEP_NS
        if last is not None and t <= last:
            t = last + 1_000_000  # equal EXIF seconds: keep order 1 ms apart
        out.append((t, m))
        last = t
    return out


def _find_license(folder: Path) -> Path | None:
    for d in (folder, *folder.parents[:2]):
        for name in LICENSE_NAMES:
            if (d / name).is_file():
                return d / name
    return None


def _load_rgb(path: Path, max_width: int | None) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise UserError(f'{path}: OpenCV cannot decode this image')
    if max_width and bgr.shape[1] > max_width:
        size = (max_width, round(bgr.shape[0] * max_width / bgr.shape[1]))
        bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def images_to_bag(
    folder: Path,
    out: Path,
    *,
    max_width: int | None = None,
    jpeg_quality: int = 92,
    fallback_hfov_deg: float = 70.0,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ImagesToBagResult:
    """Write the photos in ``folder`` to a ROS 2 bag at ``out`` (see module docstring for topics)."""
    photos = list_photos(Path(folder))
    metas = [read_photo_metadata(p) for p in photos]
    sizes = {(m.width, m.height) for m in metas}
    if len(sizes) > 1:
        raise UserError(f'{folder}: photos differ in size {sorted(sizes)}; one camera per bag is supported')
    ordered = _capture_order(metas)
    camera0, source = initial_camera(ordered[0][1], fallback_hfov_deg=fallback_hfov_deg)
    n_gps = n_att = 0
    out = Path(out)
    with BagWriter(out, overwrite=overwrite) as bag:
        for i, (stamp, meta) in enumerate(ordered):
            rgb = _load_rgb(meta.path, max_width)
            camera = camera0.scaled(rgb.shape[1] / camera0.width, rgb.shape[0] / camera0.height)
            header = msg_utils.make_header(stamp, FRAME_ID, flavor='rosbags')
            img = msg_utils.numpy_to_compressed_image(
                rgb, 'jpeg', encoding='rgb8', quality=jpeg_quality, header=header, flavor='rosbags'
            )
            bag.write(TOPICS['image'], img, stamp)
            info = msg_utils.pinhole_to_camera_info(camera, header=header, flavor='rosbags')
            bag.write(TOPICS['camera_info'], info, stamp)
            if meta.latitude_deg is not None and meta.longitude_deg is not None:  # meta.has_gps
                fix = msg_utils.GeoFix(
                    stamp_ns=stamp,
                    frame_id=FRAME_ID,
                    latitude_deg=meta.latitude_deg,
                    longitude_deg=meta.longitude_deg,
                    altitude_m=meta.altitude_m if meta.altitude_m is not None else float('nan'),
                    status=0,
                    service=1,
                )
                bag.write(TOPICS['navsat'], msg_utils.fix_to_navsatfix(fix, flavor='rosbags'), stamp)
                n_gps += 1
            if meta.gimbal is not None:
                q = quaternion_from_rotation(meta.gimbal.rotation_enu())
                att = msg_utils.new_message(
                    'geometry_msgs/msg/QuaternionStamped',
                    'rosbags',
                    header=msg_utils.make_header(stamp, 'enu', flavor='rosbags'),
                    quaternion=msg_utils.new_message(
                        'geometry_msgs/msg/Quaternion', 'rosbags', x=q[0], y=q[1], z=q[2], w=q[3]
                    ),
                )
                bag.write(TOPICS['attitude'], att, stamp)
                n_att += 1
            if progress is not None:
                progress(i + 1, len(ordered))
    license_src = _find_license(Path(folder).resolve())
    license_dst = None
    if license_src is not None:
        license_dst = out / 'LICENSE'
        shutil.copyfile(license_src, license_dst)
    else:
        LOG.info('no LICENSE found beside %s: none copied into the bag', folder)
    return ImagesToBagResult(out, len(ordered), n_gps, n_att, source, license_dst)
