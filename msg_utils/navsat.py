# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``sensor_msgs/NavSatFix`` <-> :class:`GeoFix`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, make_header, new_message, stamp_to_ns

__all__ = ['GeoFix', 'fix_to_navsatfix', 'navsatfix_to_fix']

# sensor_msgs/NavSatStatus.status and NavSatFix.position_covariance_type values.
STATUS_NO_FIX = -1
STATUS_FIX = 0
COVARIANCE_TYPE_UNKNOWN = 0


@dataclass(frozen=True, eq=False)
class GeoFix:
    """One GNSS fix: WGS84 degrees, altitude in metres above the WGS84 ellipsoid (NaN = none).

    ``status`` is NavSatStatus.status (-1 no fix, 0 fix, 1 SBAS, 2 GBAS), ``service`` its bitmask;
    ``covariance`` is the 3x3 position covariance in m^2 in the local ENU tangent frame
    (row-major in the message), ``covariance_type`` NavSatFix.COVARIANCE_TYPE_* (0 = unknown).
    """

    stamp_ns: int
    frame_id: str
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    status: int = STATUS_FIX
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))
    covariance_type: int = COVARIANCE_TYPE_UNKNOWN
    service: int = 0

    def __post_init__(self) -> None:
        cov = np.array(self.covariance, dtype=np.float64).reshape(3, 3)
        cov.setflags(write=False)
        object.__setattr__(self, 'covariance', cov)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GeoFix):
            return NotImplemented
        keys = (
            'stamp_ns',
            'frame_id',
            'latitude_deg',
            'longitude_deg',
            'status',
            'covariance_type',
            'service',
        )
        same_alt = self.altitude_m == other.altitude_m or (
            math.isnan(self.altitude_m) and math.isnan(other.altitude_m)
        )
        return (
            all(getattr(self, k) == getattr(other, k) for k in keys)
            and same_alt
            and np.array_equal(self.covariance, other.covariance)
        )


def navsatfix_to_fix(msg: Any) -> GeoFix:
    """:class:`GeoFix` of a ``sensor_msgs/NavSatFix`` of either flavour.

    Raises MessageError for a latitude or longitude that is not finite or out of range
    (check ``status`` first if your receiver publishes NaN without a fix).
    """
    lat, lon = float(msg.latitude), float(msg.longitude)
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        raise MessageError(f'NavSatFix.latitude {lat} is not finite degrees in [-90, 90]')
    if not (math.isfinite(lon) and abs(lon) <= 360.0):
        raise MessageError(f'NavSatFix.longitude {lon} is not finite degrees in [-360, 360]')
    cov = np.asarray(msg.position_covariance, dtype=np.float64)
    if cov.size != 9:
        raise MessageError(f'NavSatFix.position_covariance has {cov.size} elements, expected 9')
    return GeoFix(
        stamp_ns=stamp_to_ns(msg.header.stamp),
        frame_id=str(msg.header.frame_id),
        latitude_deg=lat,
        longitude_deg=lon,
        altitude_m=float(msg.altitude),
        status=int(msg.status.status),
        covariance=cov.reshape(3, 3),
        covariance_type=int(msg.position_covariance_type),
        service=int(msg.status.service),
    )


def fix_to_navsatfix(fix: GeoFix, *, flavor: Flavor = 'rclpy') -> Any:
    """``sensor_msgs/NavSatFix`` of ``fix``."""
    status = new_message('sensor_msgs/msg/NavSatStatus', flavor, status=fix.status, service=fix.service)
    return new_message(
        'sensor_msgs/msg/NavSatFix',
        flavor,
        header=make_header(fix.stamp_ns, fix.frame_id, flavor),
        status=status,
        latitude=float(fix.latitude_deg),
        longitude=float(fix.longitude_deg),
        altitude=float(fix.altitude_m),
        position_covariance=fix.covariance.ravel().copy(),
        position_covariance_type=fix.covariance_type,
    )
