# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pinhole camera model matching ``sensor_msgs/CameraInfo``.

Pixel coordinates: ``(u, v)`` with u to the right and v down, the centre of the top-left pixel at
``(0, 0)`` (the OpenCV / ROS convention). Camera coordinates: REP-103 optical frame.
Distortion models: ``plumb_bob`` (k1, k2, t1, t2, k3) and ``rational_polynomial``
(k1, k2, t1, t2, k3, k4, k5, k6), both as in OpenCV; ``equidistant`` is not supported.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['DISTORTION_MODELS', 'CameraError', 'PinholeCamera', 'Roi']

DISTORTION_MODELS = {'plumb_bob': 5, 'rational_polynomial': 8}


class CameraError(ValueError):
    """Camera parameters that cannot describe a real camera."""


@dataclass(frozen=True)
class Roi:
    """Region of interest, as ``sensor_msgs/RegionOfInterest`` (all zero = full image)."""

    x_offset: int = 0
    y_offset: int = 0
    height: int = 0
    width: int = 0
    do_rectify: bool = False


def _mat(name: str, value: ArrayLike, shape: tuple[int, ...]) -> NDArray[np.float64]:
    a = np.asarray(value, dtype=np.float64)
    if a.size != int(np.prod(shape)):
        raise CameraError(f'{name} must have {int(np.prod(shape))} elements, got {a.size}')
    a = a.reshape(shape).copy()
    if not np.all(np.isfinite(a)):
        raise CameraError(f'{name} must be finite, got {a.ravel().tolist()}')
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """Intrinsics of one camera (units: pixels; see module docstring for conventions).

    ``k`` is the 3x3 intrinsic matrix, ``d`` the distortion coefficients for
    ``distortion_model``, ``r`` the rectification rotation and ``p`` the 3x4 projection matrix
    (defaults: identity and ``[K | 0]``). Binning and ROI are kept as given in CameraInfo.
    """

    width: int
    height: int
    k: NDArray[np.float64]
    d: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = 'plumb_bob'
    r: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    p: NDArray[np.float64] | None = None
    binning_x: int = 0
    binning_y: int = 0
    roi: Roi = field(default_factory=Roi)

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraError(f'width/height must be positive, got {self.width}x{self.height}')
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))
        k = _mat('K', self.k, (3, 3))
        if not np.any(k):
            raise CameraError('K is all zeros (uncalibrated camera)')
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise CameraError(f'K focal lengths must be positive, got fx={k[0, 0]}, fy={k[1, 1]}')
        object.__setattr__(self, 'k', k)
        if self.distortion_model not in DISTORTION_MODELS and not (
            self.distortion_model == '' and np.asarray(self.d).size == 0
        ):
            raise CameraError(
                f'distortion_model {self.distortion_model!r} is not supported '
                f'(use one of {sorted(DISTORTION_MODELS)})'
            )
        d = np.asarray(self.d, dtype=np.float64).ravel()
        n = DISTORTION_MODELS.get(self.distortion_model, 0)
        if d.size > n:
            raise CameraError(f'D has {d.size} coefficients, {self.distortion_model!r} takes at most {n}')
        d = np.concatenate([d, np.zeros(n - d.size)]) if d.size < n else d
        object.__setattr__(self, 'd', _mat('D', d, (d.size,)))
        if self.distortion_model == '':
            object.__setattr__(self, 'distortion_model', 'plumb_bob')
            object.__setattr__(self, 'd', _mat('D', np.zeros(5), (5,)))
        object.__setattr__(self, 'r', _mat('R', self.r, (3, 3)))
        p = np.hstack([k, np.zeros((3, 1))]) if self.p is None or not np.any(self.p) else self.p
        object.__setattr__(self, 'p', _mat('P', p, (3, 4)))

    # -- convenience -----------------------------------------------------------------------
    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> PinholeCamera:
        """Ideal camera with a horizontal field of view in degrees and the principal point centred."""
        if not 0.0 < hfov_deg < 180.0:
            raise CameraError(f'hfov_deg must be in (0, 180), got {hfov_deg}')
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
        return cls(width, height, np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]]))

    @property
    def projection(self) -> NDArray[np.float64]:
        """``p``, the 3x4 projection matrix: never None once constructed (None means ``[K | 0]``)."""
        return cast('NDArray[np.float64]', self.p)

    @property
    def fx(self) -> float:
        return float(self.k[0, 0])

    @property
    def fy(self) -> float:
        return float(self.k[1, 1])

    @property
    def cx(self) -> float:
        return float(self.k[0, 2])

    @property
    def cy(self) -> float:
        return float(self.k[1, 2])

    @property
    def is_distorted(self) -> bool:
        return bool(np.any(self.d != 0))

    @property
    def hfov_deg(self) -> float:
        return float(np.degrees(2 * np.arctan2(self.width / 2, self.fx)))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PinholeCamera):
            return NotImplemented
        keys = ('width', 'height', 'distortion_model', 'binning_x', 'binning_y', 'roi')
        return (
            all(getattr(self, k) == getattr(other, k) for k in keys)
            and np.array_equal(self.k, other.k)
            and np.array_equal(self.d, other.d)
            and np.array_equal(self.r, other.r)
            and np.array_equal(self.projection, other.projection)
        )

    def scaled(self, sx: float, sy: float | None = None) -> PinholeCamera:
        """Camera for an image resized by ``sx`` horizontally and ``sy`` vertically (default sx).

        Uses the pixel-centre convention: ``u' = (u + 0.5) * sx - 0.5``.
        """
        sy = sx if sy is None else sy
        s = np.diag([sx, sy, 1.0])
        k = s @ self.k
        k[0, 2] = (self.k[0, 2] + 0.5) * sx - 0.5
        k[1, 2] = (self.k[1, 2] + 0.5) * sy - 0.5
        p = s @ self.projection
        p[0, 2] = (self.projection[0, 2] + 0.5) * sx - 0.5
        p[1, 2] = (self.projection[1, 2] + 0.5) * sy - 0.5
        return replace(
            self,
            width=round(self.width * sx),
            height=round(self.height * sy),
            k=k,
            p=p,
            roi=Roi(),
        )

    def cropped(self, x0: int, y0: int, x1: int, y1: int) -> PinholeCamera:
        """Camera for the pixel box ``x0 <= u < x1``, ``y0 <= v < y1`` of this camera's image (the
        principal point shifted by ``(x0, y0)``); ValueError when the box is empty or outside."""
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise CameraError(
                f'crop box (x0, y0, x1, y1) = {(x0, y0, x1, y1)} must lie within {self.width}x{self.height}'
            )
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])  # u' = u - x0, v' = v - y0
        return replace(
            self, width=x1 - x0, height=y1 - y0, k=shift @ self.k, p=shift @ self.projection, roi=Roi()
        )

    # -- projection (undistorted pinhole, K only) ---------------------------------------------
    def project(self, points_c: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Project Nx3 optical-frame points; return (Nx2 pixels, N depths z in metres).

        Distortion is ignored (use :mod:`ibr_ros.core.geometry.undistort` first); points with z <= 0 get NaN.
        """
        pts = np.asarray(points_c, dtype=np.float64).reshape(-1, 3)
        z = pts[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = (pts[:, :2] / z[:, None]) * [self.fx, self.fy] + [self.cx, self.cy]
        uv[z <= 0] = np.nan
        return uv, z

    def pixels_of(
        self, points_w: ArrayLike, t_wc: ArrayLike
    ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
        """Nearest pixel (column ``u``, row ``v``) and z-depth (m) of the world points ``points_w``
        (Nx3) that lie in front of the camera at pose ``t_wc`` (4x4 camera-to-world) and project
        into the image; the others are left out."""
        t_cw = np.linalg.inv(np.asarray(t_wc, dtype=np.float64))
        pc = np.asarray(points_w, dtype=np.float64).reshape(-1, 3) @ t_cw[:3, :3].T + t_cw[:3, 3]
        uv, z = self.project(pc[pc[:, 2] > 0])
        u, v = np.rint(uv).astype(np.int64).T
        inside = (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
        return u[inside], v[inside], z[inside]

    def backproject(self, uv: ArrayLike, depth: ArrayLike) -> NDArray[np.float64]:
        """Optical-frame points of pixels ``uv`` (Nx2) at z-depth ``depth`` (N, metres)."""
        uva = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        x = (uva[:, 0] - self.cx) / self.fx * z
        y = (uva[:, 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], axis=1)

    def pixel_rays(self) -> NDArray[np.float64]:
        """HxWx3 float64 optical-frame directions with z = 1 for every pixel centre."""
        u = (np.arange(self.width) - self.cx) / self.fx
        v = (np.arange(self.height) - self.cy) / self.fy
        rays = np.empty((self.height, self.width, 3))
        rays[..., 0] = u[None, :]
        rays[..., 1] = v[:, None]
        rays[..., 2] = 1.0
        return rays
