# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Photo metadata: EXIF capture time, focal length, GPS and DJI XMP gimbal attitude.

Pillow reads the EXIF/GPS IFDs and the XMP packet (OpenCV exposes neither). Angles are degrees.
Capture times in EXIF are local times without a zone unless ``OffsetTimeOriginal`` is present;
without it they are read as UTC, which keeps the order and spacing of the photos.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, UnidentifiedImageError

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import rotation_from_ypr
from ibr_ros.errors import UserError

__all__ = ['GimbalAttitude', 'PhotoMetadata', 'initial_camera', 'read_photo_metadata']

LOG = logging.getLogger(__name__)

_EXIF_IFD = 0x8769
_GPS_IFD = 0x8825
_TAG_MAKE, _TAG_MODEL, _TAG_DATETIME = 0x010F, 0x0110, 0x0132
_TAG_DT_ORIGINAL, _TAG_SUBSEC_ORIGINAL, _TAG_OFFSET_ORIGINAL = 0x9003, 0x9291, 0x9011
_TAG_FOCAL, _TAG_FOCAL_35 = 0x920A, 0xA405
_TAG_FP_XRES, _TAG_FP_UNIT = 0xA20E, 0xA210
_TAG_EXIF_WIDTH = 0xA002
_FP_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # focal plane resolution unit -> mm per unit
_DIAG_35MM = math.hypot(36.0, 24.0)  # 43.27 mm
_XMP_ATTR = re.compile(rb'drone-dji:(\w+)\s*=\s*"([^"]*)"')
_XMP_ELEM = re.compile(rb'<drone-dji:(\w+)>([^<]*)</drone-dji:\1>')


@dataclass(frozen=True)
class GimbalAttitude:
    """Camera attitude from DJI XMP: yaw clockwise from north, pitch (-90 = straight down), roll."""

    yaw_deg: float
    pitch_deg: float
    roll_deg: float

    def rotation_enu(self) -> np.ndarray:
        """Camera-to-world 3x3 rotation of the REP-103 optical frame in ENU."""
        return rotation_from_ypr(
            math.radians(90.0 - self.yaw_deg), math.radians(self.pitch_deg), math.radians(self.roll_deg)
        )


@dataclass(frozen=True)
class PhotoMetadata:
    """What a photo says about itself; ``None`` where it says nothing."""

    path: Path
    width: int
    height: int
    capture_time_ns: int | None
    make: str | None
    model: str | None
    focal_mm: float | None
    focal_35mm: float | None
    focal_plane_px_per_mm: float | None
    exif_width: int | None
    latitude_deg: float | None
    longitude_deg: float | None
    altitude_m: float | None
    relative_altitude_m: float | None
    gimbal: GimbalAttitude | None

    @property
    def has_gps(self) -> bool:
        return self.latitude_deg is not None and self.longitude_deg is not None


def _text(value: object) -> str | None:
    if value is None:
        return None
    s = value.decode('latin-1') if isinstance(value, bytes) else str(value)
    s = s.replace('\x00', '').strip()
    return s or None


def _float(value: Any) -> float | None:
    try:
        f = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if math.isfinite(f) else None


def _capture_time_ns(exif_ifd: dict, base: dict) -> int | None:
    stamp = _text(exif_ifd.get(_TAG_DT_ORIGINAL)) or _text(base.get(_TAG_DATETIME))
    if stamp is None:
        return None
    try:
        dt = datetime.strptime(stamp[:19], '%Y:%m:%d %H:%M:%S')
    except ValueError:
        LOG.warning('unreadable EXIF DateTimeOriginal %r', stamp)
        return None
    tz = timezone.utc
    offset = _text(exif_ifd.get(_TAG_OFFSET_ORIGINAL))
    if offset and re.fullmatch(r'[+-]\d\d:\d\d', offset):
        sign = 1 if offset[0] == '+' else -1
        tz = timezone(sign * timedelta(hours=int(offset[1:3]), minutes=int(offset[4:6])))
    ns = int(dt.replace(tzinfo=tz).timestamp()) * 1_000_000_000
    subsec = _text(exif_ifd.get(_TAG_SUBSEC_ORIGINAL))
    if subsec and subsec.isdigit():
        ns += int(float('0.' + subsec) * 1e9)
    return ns


def _dms(value: Any, ref: object, negative: str) -> float | None:
    try:
        d, m, s = (float(x) for x in value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    deg = d + m / 60.0 + s / 3600.0
    if not math.isfinite(deg):
        return None
    return -deg if _text(ref) == negative else deg


def _xmp_dji(xmp: bytes | str | None) -> dict[str, str]:
    if not xmp:
        return {}
    raw = xmp.encode('utf-8') if isinstance(xmp, str) else xmp
    found = {k.decode(): v.decode('utf-8', 'replace') for k, v in _XMP_ATTR.findall(raw)}
    found.update({k.decode(): v.decode('utf-8', 'replace') for k, v in _XMP_ELEM.findall(raw)})
    return found


def read_photo_metadata(path: Path) -> PhotoMetadata:
    """Read size and metadata of one photo; raises UserError if it is not a readable image."""
    try:
        with Image.open(path) as im:
            width, height = im.size
            exif = im.getexif()
            xmp = im.info.get('xmp')
    except (OSError, UnidentifiedImageError) as exc:
        raise UserError(f'{path}: not a readable image ({exc})') from exc
    exif_ifd = dict(exif.get_ifd(_EXIF_IFD))
    gps = dict(exif.get_ifd(_GPS_IFD))
    dji = _xmp_dji(xmp)

    fp_xres = _float(exif_ifd.get(_TAG_FP_XRES))
    fp_unit = _FP_UNIT_MM.get(int(exif_ifd.get(_TAG_FP_UNIT, 2) or 2))
    px_per_mm = fp_xres / fp_unit if fp_xres and fp_unit else None

    lat = _dms(gps.get(2), gps.get(1), 'S')
    lon = _dms(gps.get(4), gps.get(3), 'W')
    alt = _float(gps.get(6))
    if alt is not None and gps.get(5) in (1, b'\x01'):
        alt = -alt
    if alt is None:
        alt = _float(dji.get('AbsoluteAltitude'))

    gimbal = None
    keys = ('GimbalYawDegree', 'GimbalPitchDegree', 'GimbalRollDegree')
    if all(k in dji for k in keys):
        yaw, pitch, roll = (_float(dji[k]) for k in keys)
        if yaw is not None and pitch is not None and roll is not None:
            gimbal = GimbalAttitude(yaw, pitch, roll)

    exif_width = exif_ifd.get(_TAG_EXIF_WIDTH)
    return PhotoMetadata(
        path=Path(path),
        width=int(width),
        height=int(height),
        capture_time_ns=_capture_time_ns(exif_ifd, dict(exif)),
        make=_text(exif.get(_TAG_MAKE)),
        model=_text(exif.get(_TAG_MODEL)),
        focal_mm=_float(exif_ifd.get(_TAG_FOCAL)),
        focal_35mm=_float(exif_ifd.get(_TAG_FOCAL_35)) or None,
        focal_plane_px_per_mm=px_per_mm,
        exif_width=int(exif_width) if isinstance(exif_width, int) and exif_width > 0 else None,
        latitude_deg=lat,
        longitude_deg=lon,
        altitude_m=alt,
        relative_altitude_m=_float(dji.get('RelativeAltitude')),
        gimbal=gimbal,
    )


def initial_camera(meta: PhotoMetadata, *, fallback_hfov_deg: float = 70.0) -> tuple[PinholeCamera, str]:
    """Initial pinhole guess for ``meta``'s image size and how it was derived.

    In order of preference:

    1. ``FocalLength`` (mm) with ``FocalPlaneXResolution`` (sensor pixels per mm), scaled from
       ``ExifImageWidth`` to the actual width.
    2. ``FocalLengthIn35mmFilm``: by the CIPA definition it matches the 43.27 mm diagonal of 35 mm
       film to the *sensor* diagonal. Assumption: the sensor is as wide as the image and has the
       image's aspect ratio when that is 3:2 or squarer, else 4:3 (a 16:9 photo is taken as a crop
       of a 4:3 sensor, as on DJI drones).
    3. ``fallback_hfov_deg`` (horizontal field of view), with a warning.

    The principal point is the image centre and there is no distortion: refine with SfM.
    """
    w, h = meta.width, meta.height
    if meta.focal_mm and meta.focal_plane_px_per_mm and meta.exif_width:
        f = meta.focal_mm * meta.focal_plane_px_per_mm * w / meta.exif_width
        how = f'EXIF FocalLength {meta.focal_mm} mm x FocalPlaneXResolution'
    elif meta.focal_35mm:
        aspect = h / w if h / w >= 2.0 / 3.0 else 0.75
        f = meta.focal_35mm * w * math.hypot(1.0, aspect) / _DIAG_35MM
        how = f'EXIF FocalLengthIn35mmFilm {meta.focal_35mm:g} mm (sensor aspect {aspect:.3f} assumed)'
    else:
        LOG.warning(
            '%s: no focal length in EXIF; assuming a %.1f deg horizontal FOV', meta.path, fallback_hfov_deg
        )
        cam = PinholeCamera.from_fov(w, h, fallback_hfov_deg)
        return cam, f'assumed horizontal FOV {fallback_hfov_deg:g} deg (no EXIF focal length)'
    k = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    return PinholeCamera(w, h, k), how
