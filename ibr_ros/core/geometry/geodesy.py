# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""WGS84 geodetic <-> ECEF <-> local ENU coordinates, vectorised with numpy.

Latitude/longitude in degrees, altitude in metres above the WGS84 ellipsoid (as in
``sensor_msgs/NavSatFix``; not above mean sea level). ENU: x east, y north, z up in metres,
tangent to the ellipsoid at ``origin = (lat_deg, lon_deg, alt_m)``, matching the ``map`` frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    'WGS84_A',
    'WGS84_F',
    'ecef_to_enu',
    'ecef_to_geodetic',
    'enu_to_ecef',
    'enu_to_geodetic',
    'geodetic_to_ecef',
    'geodetic_to_enu',
]

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)

Arr = NDArray[np.float64]
Origin = tuple[float, float, float]


def _check_lat(lat_deg: Arr, name: str = 'latitude') -> None:
    if not np.all(np.abs(lat_deg) <= 90.0):
        bad = lat_deg[~(np.abs(lat_deg) <= 90.0)]
        raise ValueError(f'{name} must be finite degrees in [-90, 90], got {bad.ravel()[:3].tolist()}')


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike) -> tuple[Arr, Arr, Arr]:
    """ECEF (x, y, z) metres of WGS84 latitude/longitude (degrees) and ellipsoidal altitude (m)."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    _check_lat(lat)
    phi, lam = np.radians(lat), np.radians(np.asarray(lon_deg, dtype=np.float64))
    h = np.asarray(alt_m, dtype=np.float64)
    n = WGS84_A / np.sqrt(1.0 - _E2 * np.sin(phi) ** 2)
    x = (n + h) * np.cos(phi) * np.cos(lam)
    y = (n + h) * np.cos(phi) * np.sin(lam)
    z = (n * (1.0 - _E2) + h) * np.sin(phi)
    return x, y, z


def ecef_to_geodetic(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> tuple[Arr, Arr, Arr]:
    """WGS84 (latitude deg, longitude deg, ellipsoidal altitude m) of ECEF metres.

    Fixed-point iteration on latitude (converges to < 1e-12 rad within 8 steps for points
    outside the Earth's core region); valid at the poles.
    """
    xa, ya, za = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    p = np.hypot(xa, ya)
    lam = np.arctan2(ya, xa)
    phi = np.arctan2(za, p * (1.0 - _E2))
    for _ in range(8):
        n = WGS84_A / np.sqrt(1.0 - _E2 * np.sin(phi) ** 2)
        phi = np.arctan2(za + _E2 * n * np.sin(phi), p)
    s = np.sin(phi)
    h = p * np.cos(phi) + za * s - WGS84_A * np.sqrt(1.0 - _E2 * s * s)
    return np.degrees(phi), np.degrees(lam), h


def _enu_rotation(origin: Origin) -> tuple[Arr, Arr]:
    """Rows: east, north, up unit vectors in ECEF at ``origin``; and the origin in ECEF."""
    lat0, lon0, alt0 = (float(v) for v in origin)
    if not (np.isfinite(lon0) and np.isfinite(alt0)):
        raise ValueError(f'origin must be finite (lat_deg, lon_deg, alt_m), got {origin}')
    _check_lat(np.asarray(lat0), 'origin latitude')
    phi, lam = np.radians(lat0), np.radians(lon0)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    r = np.array([[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])
    return r, np.array(geodetic_to_ecef(lat0, lon0, alt0))


def _stack(a: ArrayLike, b: ArrayLike, c: ArrayLike) -> Arr:
    return np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (a, b, c))))


def ecef_to_enu(x: ArrayLike, y: ArrayLike, z: ArrayLike, origin: Origin) -> tuple[Arr, Arr, Arr]:
    """Local ENU (east, north, up) metres of ECEF metres, relative to ``origin``."""
    r, o = _enu_rotation(origin)
    d = _stack(x, y, z)
    d = d - o.reshape((3,) + (1,) * (d.ndim - 1))
    enu = np.tensordot(r, d, axes=1)
    return enu[0], enu[1], enu[2]


def enu_to_ecef(e: ArrayLike, n: ArrayLike, u: ArrayLike, origin: Origin) -> tuple[Arr, Arr, Arr]:
    """ECEF metres of local ENU (east, north, up) metres relative to ``origin``."""
    r, o = _enu_rotation(origin)
    d = _stack(e, n, u)
    xyz = np.tensordot(r.T, d, axes=1) + o.reshape((3,) + (1,) * (d.ndim - 1))
    return xyz[0], xyz[1], xyz[2]


def geodetic_to_enu(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: Origin
) -> tuple[Arr, Arr, Arr]:
    """Local ENU (east, north, up) metres of WGS84 points, relative to ``origin`` (lat, lon, alt).

    Inputs broadcast against each other; outputs have the broadcast shape.
    """
    return ecef_to_enu(*geodetic_to_ecef(lat_deg, lon_deg, alt_m), origin)


def enu_to_geodetic(e: ArrayLike, n: ArrayLike, u: ArrayLike, origin: Origin) -> tuple[Arr, Arr, Arr]:
    """WGS84 (latitude deg, longitude deg, ellipsoidal altitude m) of ENU metres relative to ``origin``."""
    return ecef_to_geodetic(*enu_to_ecef(e, n, u, origin))
