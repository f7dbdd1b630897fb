# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Camera registration: structure from motion with COLMAP (pycolmap, CPU) and GPS alignment.

:func:`register_images` writes the images to a work folder, extracts SIFT features, matches them,
runs COLMAP's incremental mapper with ONE camera shared by all images and converts the largest
reconstruction to ibr_ros conventions (:mod:`ibr_ros.core.geometry`):

* poses are 4x4 camera-to-world ``T_wc`` (the inverse of COLMAP's ``cam_from_world``); COLMAP's
  camera frame has the same axes as the REP-103 optical frame (z forward, x right, y down);
* pixels have the top-left pixel centre at (0, 0) (COLMAP puts it at (0.5, 0.5): 0.5 is
  subtracted from principal points and keypoints);
* the refined camera is a :class:`PinholeCamera` of the input image size with ``plumb_bob``
  distortion: COLMAP's radial ``k`` / ``k1, k2`` and OpenCV ``p1, p2`` use the same normalised
  coordinates as OpenCV, so SIMPLE_RADIAL gives ``D = [k, 0, 0, 0, 0]``, RADIAL
  ``[k1, k2, 0, 0, 0]``, OPENCV ``[k1, k2, p1, p2, 0]``.

Matching: exhaustive for up to ``SfmOptions.exhaustive_max_images`` images (most robust, and cheap
at that size), else sequential (capture order, ``sequential_overlap``) plus spatial matching
between GPS neighbours when positions are known.

With ``gps_enu`` positions for at least 3 non-collinear registered images, a similarity transform
from the SfM camera centres to the GPS positions (Umeyama's method inside RANSAC, then refitted
on the inliers) is applied to poses and points: the result is in ENU metres (``metric=True``).
Otherwise the model keeps SfM's arbitrary frame and scale (``metric=False``).
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.registration.colmap import pycolmap as _import_pycolmap

if TYPE_CHECKING:  # the module itself, for its stubs; at run time through the signal-safe import
    import pycolmap
else:
    pycolmap = _import_pycolmap()

__all__ = [
    'CameraModel',
    'GpsAlignment',
    'SfmError',
    'SfmOptions',
    'SfmResult',
    'register_images',
    'robust_similarity',
    'similarity_from_orientations',
    'umeyama',
]

LOG = logging.getLogger(__name__)

CameraModel = Literal['SIMPLE_PINHOLE', 'PINHOLE', 'SIMPLE_RADIAL', 'RADIAL', 'OPENCV']
#: COLMAP camera model -> indices of (fx, fy, cx, cy) and of the plumb_bob D entries in its params.
_MODELS: dict[str, tuple[tuple[int, int, int, int], tuple[int, ...]]] = {
    'SIMPLE_PINHOLE': ((0, 0, 1, 2), ()),
    'PINHOLE': ((0, 1, 2, 3), ()),
    'SIMPLE_RADIAL': ((0, 0, 1, 2), (3,)),
    'RADIAL': ((0, 0, 1, 2), (3, 4)),
    'OPENCV': ((0, 1, 2, 3), (4, 5, 6, 7)),
}
_DB = 'database.db'


class SfmError(ValueError):
    """Registration impossible: bad input, or no reconstruction could be made."""


@dataclass(frozen=True)
class SfmOptions:
    """Settings of :func:`register_images` (pixels refer to the input images).

    ``max_image_size``: longest side (px) SIFT works at (keypoints are scaled back);
    ``first_octave``: -1 upsamples images 2x for more features (slower), 0 does not;
    ``camera_model``: COLMAP model of the shared camera; ``refine_*``: what bundle adjustment may
    change; ``gps_inlier_m``: RANSAC threshold (m) of the GPS alignment; ``min_gps_spread_m``:
    the GPS positions' second principal spread (m) below which they count as collinear;
    ``prior_focal_tolerance``: with a given ``camera``, the refined focal length is replaced by the
    given one (and bundle adjustment rerun) when that raises the mean reprojection error by at most
    this fraction, i.e. when the images do not determine the focal length: nadir views of flat
    ground cannot tell focal length from altitude (None: always keep the refined focal length);
    ``seed``: RANSAC and mapper seed (results may still vary slightly with ``num_threads`` > 1);
    ``num_threads``: -1 = all cores; ``verbose``: COLMAP's INFO/WARNING log on stderr.
    """

    max_image_size: int = 1600
    max_num_features: int = 4096
    first_octave: int = -1
    camera_model: CameraModel = 'SIMPLE_RADIAL'
    refine_focal_length: bool = True
    refine_principal_point: bool = False
    refine_distortion: bool = True
    exhaustive_max_images: int = 30
    sequential_overlap: int = 10
    spatial_max_distance_m: float = 150.0
    spatial_max_neighbors: int = 20
    min_num_matches: int = 15
    gps_inlier_m: float = 5.0
    min_gps_spread_m: float = 1.0
    prior_focal_tolerance: float | None = 0.05
    ransac_iterations: int = 500
    seed: int = 0
    num_threads: int = -1
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.camera_model not in _MODELS:
            raise ValueError(f'camera_model must be one of {sorted(_MODELS)}, got {self.camera_model!r}')
        if self.max_image_size < 100 or self.max_num_features < 100:
            raise ValueError(
                f'max_image_size and max_num_features must be >= 100, '
                f'got {self.max_image_size} and {self.max_num_features}'
            )
        if self.gps_inlier_m <= 0 or self.sequential_overlap < 1:
            raise ValueError('gps_inlier_m must be > 0 and sequential_overlap >= 1')


@dataclass(frozen=True, eq=False)
class GpsAlignment:
    """Similarity ``p_enu = scale * R @ p_sfm + t`` (``matrix`` = 4x4 ``[[s R, t], [0, 1]]``).

    ``rms_m`` and ``max_m`` are the camera centre residuals (m) over the ``inliers`` (indices into
    the input images); ``num_used`` images had both a GPS position and a registered pose.
    """

    matrix: NDArray[np.float64]
    scale: float
    rms_m: float
    max_m: float
    inliers: NDArray[np.int64]
    num_used: int


@dataclass(frozen=True, eq=False)
class SfmResult:
    """Registered cameras and sparse points (world: ENU metres if ``metric``, else SfM frame).

    Per input image i: ``poses[i]`` 4x4 ``T_wc`` (NaN if not ``registered[i]``),
    ``observations[i]`` Mx3 float64 ``(u, v, z)``: keypoint pixel in the input image (distorted
    as ``camera.d`` says) and z-depth of its 3D point in that camera (world units), and
    ``observation_ids[i]`` (M,) indices of those points in ``points``. Points: ``points`` Px3,
    ``colors`` Px3 uint8 RGB, ``track_lengths`` (P,) images observing each point,
    ``point_errors`` (P,) mean reprojection error (px). ``timing`` holds seconds per stage.
    SIFT keeps up to two orientations per keypoint, so a pixel may observe two (nearly equal) points.
    """

    poses: NDArray[np.float64]
    registered: NDArray[np.bool_]
    camera: PinholeCamera
    points: NDArray[np.float64]
    colors: NDArray[np.uint8]
    track_lengths: NDArray[np.int64]
    point_errors: NDArray[np.float64]
    observations: tuple[NDArray[np.float64], ...]
    observation_ids: tuple[NDArray[np.int64], ...]
    mean_reprojection_error_px: float
    metric: bool
    alignment: GpsAlignment | None
    matching: str
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def num_registered(self) -> int:
        return int(self.registered.sum())

    def camera_centres(self) -> NDArray[np.float64]:
        """Nx3 camera positions (NaN rows for unregistered images)."""
        return self.poses[:, :3, 3].copy()

    def summary(self) -> dict[str, object]:
        """JSON-friendly summary: counts, camera, quality, alignment and timing."""
        a = self.alignment
        return {
            'images': len(self.registered),
            'registered': self.num_registered,
            'points': len(self.points),
            'mean_reprojection_error_px': self.mean_reprojection_error_px,
            'metric': self.metric,
            'matching': self.matching,
            'camera': {
                'width': self.camera.width,
                'height': self.camera.height,
                'k': self.camera.k.tolist(),
                'd': self.camera.d.tolist(),
                'distortion_model': self.camera.distortion_model,
            },
            'alignment': None
            if a is None
            else {'scale': a.scale, 'rms_m': a.rms_m, 'max_m': a.max_m, 'inliers': len(a.inliers)},
            'timing_s': dict(self.timing),
        }


# -- similarity estimation ------------------------------------------------------------------------
def umeyama(src: NDArray[np.float64], dst: NDArray[np.float64]) -> NDArray[np.float64]:
    """4x4 similarity ``[[s R, t], [0, 1]]`` minimising ``sum |s R src + t - dst|^2`` (Nx3, N >= 3)."""
    n = len(src)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / n
    u, sig, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    r = u @ sign @ vt
    var_s = float((xs**2).sum() / n)
    s = float(np.trace(np.diag(sig) @ sign) / var_s) if var_s > 0 else 1.0
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = mu_d - s * r @ mu_s
    return m


def similarity_from_orientations(
    src: NDArray[np.float64], dst: NDArray[np.float64], r_src: NDArray[np.float64], r_dst: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """4x4 similarity ``[[s R, t], [0, 1]]`` taking cameras ``src`` (Nx3 centres, Nx3x3 orientations
    ``r_src``) onto ``dst``, ``r_dst``: R averaged from the orientations (the SO(3) projection of
    ``sum r_dst r_src^T``; well determined even for near-collinear centres, whose roll about the path
    a centre fit leaves free), then s and t by least squares on the centres. None if s <= 0.
    """
    u, _, vt = np.linalg.svd(np.einsum('nij,nkj->ik', r_dst, r_src))
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    xs, xd = src - src.mean(0), dst - dst.mean(0)
    den = float((xs**2).sum())
    s = float(np.sum((xs @ r.T) * xd) / den) if den > 0 else 0.0
    if not s > 0:
        return None
    m = np.eye(4)
    m[:3, :3] = s * r
    m[:3, 3] = dst.mean(0) - s * r @ src.mean(0)
    return m


def _spread(p: NDArray[np.float64]) -> float:
    """Second singular value (m, RMS over points) of centred positions: ~0 for collinear sets."""
    if len(p) < 3:
        return 0.0
    return float(np.linalg.svd(p - p.mean(0), compute_uv=False)[1] / math.sqrt(len(p)))


def _residuals(m: NDArray[np.float64], src: NDArray[np.float64], dst: NDArray[np.float64]) -> NDArray:
    return np.linalg.norm(src @ m[:3, :3].T + m[:3, 3] - dst, axis=1)


def robust_similarity(
    src: NDArray[np.float64],
    dst: NDArray[np.float64],
    *,
    inlier_m: float = 5.0,
    iterations: int = 500,
    seed: int = 0,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]] | None:
    """Similarity ``dst ~ s R src + t`` robust to outliers, and its inlier mask (residual < ``inlier_m``).

    RANSAC over 3-point :func:`umeyama` fits (MSAC score), then refitted on the inliers. None when
    fewer than 3 points agree or the points are (nearly) collinear.
    """
    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    n = len(src)
    if n < 3 or src.shape != dst.shape or src.shape[1:] != (3,):
        raise ValueError(f'src and dst must be Nx3 with N >= 3, got {src.shape} and {dst.shape}')
    rng = np.random.default_rng(seed)
    tiny = 1e-6 * max(float(np.ptp(dst, axis=0).max()), 1e-12)
    best: NDArray[np.bool_] | None = None
    best_cost = math.inf
    for _ in range(iterations if n > 3 else 1):
        idx = rng.choice(n, 3, replace=False)
        if _spread(dst[idx]) <= tiny or _spread(src[idx]) <= 0:
            continue
        res = _residuals(umeyama(src[idx], dst[idx]), src, dst)
        inl = res < inlier_m
        cost = float(np.minimum(res, inlier_m).sum())
        if best is None or inl.sum() > best.sum() or (inl.sum() == best.sum() and cost < best_cost):
            best, best_cost = inl, cost
    if best is None or best.sum() < 3:
        return None
    for _ in range(5):  # refit on the inliers until the set is stable
        inl = _residuals(umeyama(src[best], dst[best]), src, dst) < inlier_m
        if inl.sum() < 3 or np.array_equal(inl, best):
            break
        best = inl
    return umeyama(src[best], dst[best]), best


# -- input checks ---------------------------------------------------------------------------------
def _check_inputs(
    images: Sequence[np.ndarray], camera: PinholeCamera | None, gps_enu: np.ndarray | None
) -> tuple[int, int, NDArray[np.float64] | None]:
    if len(images) < 2:
        raise SfmError(f'registration needs at least 2 images, got {len(images)}')
    h, w = np.asarray(images[0]).shape[:2]
    for i, im in enumerate(images):
        a = np.asarray(im)
        if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
            raise SfmError(f'image {i} must be HxWx3 uint8 RGB, got {a.dtype} {a.shape}')
        if a.shape[:2] != (h, w):
            raise SfmError(
                f'all images must have one size: image 0 is {w}x{h}, image {i} {a.shape[1]}x{a.shape[0]}'
            )
    if camera is not None and (camera.width, camera.height) != (w, h):
        raise SfmError(f'camera is {camera.width}x{camera.height} but the images are {w}x{h}')
    gps = None
    if gps_enu is not None:
        gps = np.asarray(gps_enu, dtype=np.float64)
        if gps.shape != (len(images), 3):
            raise SfmError(f'gps_enu must be {len(images)}x3 (one ENU row per image), got {gps.shape}')
        gps = gps.copy()
        gps[~np.all(np.isfinite(gps), axis=1)] = np.nan
    return w, h, gps


# -- COLMAP stages --------------------------------------------------------------------------------
def _camera_params(camera: PinholeCamera, model: str) -> str:
    """COLMAP params string of ``camera`` for ``model`` (principal point + 0.5 px)."""
    f, cx, cy = 0.5 * (camera.fx + camera.fy), camera.cx + 0.5, camera.cy + 0.5
    d = np.zeros(5) if camera.distortion_model != 'plumb_bob' else camera.d
    params = {
        'SIMPLE_PINHOLE': [f, cx, cy],
        'PINHOLE': [camera.fx, camera.fy, cx, cy],
        'SIMPLE_RADIAL': [f, cx, cy, d[0]],
        'RADIAL': [f, cx, cy, d[0], d[1]],
        'OPENCV': [camera.fx, camera.fy, cx, cy, d[0], d[1], d[2], d[3]],
    }[model]
    return ','.join(repr(float(p)) for p in params)


def _write_images(images: Sequence[np.ndarray], folder: Path) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for i, im in enumerate(images):
        name = f'{i:06d}.png'
        if not cv2.imwrite(
            str(folder / name),
            cv2.cvtColor(np.asarray(im), cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_PNG_COMPRESSION, 1],
        ):
            raise SfmError(f'cannot write image {i} to {folder}')
        names.append(name)
    return names


def _write_pose_priors(db_path: Path, names: list[str], gps: NDArray[np.float64]) -> None:
    db = pycolmap.Database.open(db_path)
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        for name, p in zip(names, gps):
            if np.all(np.isfinite(p)) and name in by_name:
                prior = pycolmap.PosePrior(
                    corr_data_id=by_name[name].data_id,
                    position=p,
                    coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                )
                db.write_pose_prior(prior)
    finally:
        db.close()


def _match(db_path: Path, n: int, gps: NDArray[np.float64] | None, o: SfmOptions) -> str:
    """Run the matchers; return a description of what was done."""
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = o.num_threads
    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = o.min_num_matches
    vo.ransac.random_seed = o.seed
    cpu = pycolmap.Device.cpu
    if n <= o.exhaustive_max_images:
        pycolmap.match_exhaustive(db_path, matching_options=mo, verification_options=vo, device=cpu)
        return 'exhaustive'
    so = pycolmap.SequentialPairingOptions()
    so.overlap = o.sequential_overlap
    so.num_threads = o.num_threads
    pycolmap.match_sequential(
        db_path, matching_options=mo, pairing_options=so, verification_options=vo, device=cpu
    )
    done = f'sequential (overlap {o.sequential_overlap})'
    if gps is not None and np.isfinite(gps[:, 0]).sum() >= 2:
        po = pycolmap.SpatialPairingOptions()
        po.ignore_z = False
        po.max_distance = o.spatial_max_distance_m
        po.max_num_neighbors = o.spatial_max_neighbors
        po.num_threads = o.num_threads
        pycolmap.match_spatial(
            db_path, matching_options=mo, pairing_options=po, verification_options=vo, device=cpu
        )
        done += f' + spatial ({o.spatial_max_distance_m:g} m, {o.spatial_max_neighbors} neighbours)'
    return done


def _map(db_path: Path, image_dir: Path, out_dir: Path, o: SfmOptions) -> pycolmap.Reconstruction | None:
    po = pycolmap.IncrementalPipelineOptions()
    po.min_num_matches = o.min_num_matches
    po.multiple_models = True
    po.min_model_size = 2
    po.random_seed = o.seed
    po.num_threads = o.num_threads
    po.extract_colors = True
    po.ba_refine_focal_length = o.refine_focal_length
    po.ba_refine_principal_point = o.refine_principal_point
    po.ba_refine_extra_params = o.refine_distortion
    po.mapper.abs_pose_refine_focal_length = o.refine_focal_length
    po.mapper.abs_pose_refine_extra_params = o.refine_distortion
    po.mapper.random_seed = o.seed
    out_dir.mkdir(parents=True, exist_ok=True)
    recs = pycolmap.incremental_mapping(db_path, image_dir, out_dir, options=po)
    if not recs:
        return None
    return max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))


def _prefer_prior_focal(
    rec: pycolmap.Reconstruction, camera: PinholeCamera, o: SfmOptions
) -> pycolmap.Reconstruction:
    """``rec`` re-adjusted with the focal length of ``camera`` if the data hardly prefer another."""
    (ifx, ify, _, _), _ = _MODELS[o.camera_model]
    cam = next(iter(rec.cameras.values()))
    prior = np.asarray(cam.params, dtype=np.float64).copy()
    prior[ifx], prior[ify] = (camera.fx, camera.fy) if ifx != ify else (0.5 * (camera.fx + camera.fy),) * 2
    if np.allclose(prior, cam.params, rtol=1e-9, atol=0.0):
        return rec
    fixed = pycolmap.Reconstruction(rec)
    next(iter(fixed.cameras.values())).params = prior
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = False
    ba.refine_principal_point = o.refine_principal_point
    ba.refine_extra_params = o.refine_distortion
    ba.print_summary = False
    pycolmap.bundle_adjustment(fixed, ba)
    fixed.update_point_3d_errors()
    err, err_fixed = rec.compute_mean_reprojection_error(), fixed.compute_mean_reprojection_error()
    f_ref, f_prior = float(cam.params[ifx]), float(prior[ifx])
    if err_fixed <= err * (1.0 + float(o.prior_focal_tolerance or 0.0)):
        LOG.info(
            'focal length %.1f px kept: refining it to %.1f px lowers the reprojection error only from '
            '%.3f to %.3f px',
            f_prior,
            f_ref,
            err_fixed,
            err,
        )
        return fixed
    LOG.info(
        'focal length refined from %.1f to %.1f px (reprojection error %.3f -> %.3f px)',
        f_prior,
        f_ref,
        err_fixed,
        err,
    )
    return rec


# -- conversion -----------------------------------------------------------------------------------
def _pinhole(cam: pycolmap.Camera, model: str) -> PinholeCamera:
    (ifx, ify, icx, icy), idist = _MODELS[model]
    p = np.asarray(cam.params, dtype=np.float64)
    k = np.array([[p[ifx], 0.0, p[icx] - 0.5], [0.0, p[ify], p[icy] - 0.5], [0.0, 0.0, 1.0]])
    d = np.zeros(5)
    d[: len(idist)] = p[list(idist)]
    return PinholeCamera(int(cam.width), int(cam.height), k, d, 'plumb_bob')


def _convert(rec: pycolmap.Reconstruction, names: list[str], model: str, matching: str) -> SfmResult:
    n = len(names)
    index = {name: i for i, name in enumerate(names)}
    ids = np.array(sorted(rec.point3D_ids()), dtype=np.int64)
    row = {int(pid): j for j, pid in enumerate(ids)}
    pts = [rec.points3D[int(pid)] for pid in ids]
    points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in pts], dtype=np.int64)
    errors = np.array([p.error for p in pts], dtype=np.float64)
    poses = np.full((n, 4, 4), np.nan)
    registered = np.zeros(n, dtype=bool)
    obs: list[NDArray[np.float64]] = [np.zeros((0, 3)) for _ in range(n)]
    obs_ids: list[NDArray[np.int64]] = [np.zeros(0, dtype=np.int64) for _ in range(n)]
    for image in rec.images.values():
        if not image.has_pose or image.name not in index:
            continue
        i = index[image.name]
        cw = np.vstack([image.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]])
        poses[i] = np.linalg.inv(cw)
        poses[i][3] = [0.0, 0.0, 0.0, 1.0]
        registered[i] = True
        p2d = image.get_observation_points2D()
        if len(p2d):
            j = np.array([row[int(p.point3D_id)] for p in p2d], dtype=np.int64)
            uv = np.array([p.xy for p in p2d], dtype=np.float64) - 0.5
            z = points[j] @ cw[2, :3] + cw[2, 3]
            obs[i], obs_ids[i] = np.column_stack([uv, z]), j
    cams = list(rec.cameras.values())
    if len(cams) != 1:
        raise SfmError(f'expected one shared camera, the reconstruction has {len(cams)}')
    return SfmResult(
        poses=poses,
        registered=registered,
        camera=_pinhole(cams[0], model),
        points=points,
        colors=colors,
        track_lengths=tracks,
        point_errors=errors,
        observations=tuple(obs),
        observation_ids=tuple(obs_ids),
        mean_reprojection_error_px=float(rec.compute_mean_reprojection_error()),
        metric=False,
        alignment=None,
        matching=matching,
    )


def _align(
    rec: pycolmap.Reconstruction, names: list[str], gps: NDArray[np.float64], o: SfmOptions
) -> GpsAlignment | None:
    """Fit and apply the SfM -> ENU similarity to ``rec``; None (logged) when it cannot be done."""
    index = {name: i for i, name in enumerate(names)}
    centres, targets, used = [], [], []
    for image in rec.images.values():
        i = index.get(image.name, -1)
        if i >= 0 and image.has_pose and np.all(np.isfinite(gps[i])):
            centres.append(image.projection_center())
            targets.append(gps[i])
            used.append(i)
    if len(used) < 3 or _spread(np.array(targets)) < o.min_gps_spread_m:
        LOG.warning(
            'GPS alignment skipped: %d registered images with GPS, spread %.2f m (need >= 3 non-collinear, '
            'spread >= %.2f m); the model stays in the SfM frame and scale',
            len(used),
            _spread(np.array(targets)) if used else 0.0,
            o.min_gps_spread_m,
        )
        return None
    src, dst = np.array(centres, dtype=np.float64), np.array(targets, dtype=np.float64)
    fit = robust_similarity(src, dst, inlier_m=o.gps_inlier_m, iterations=o.ransac_iterations, seed=o.seed)
    if fit is None:
        LOG.warning('GPS alignment failed: fewer than 3 positions agree within %.1f m', o.gps_inlier_m)
        return None
    m, inl = fit
    scale = float(np.cbrt(np.linalg.det(m[:3, :3])))
    rec.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(m[:3, :3] / scale), m[:3, 3]))
    res = _residuals(m, src, dst)[inl]
    if (~inl).any():
        LOG.warning(
            'GPS alignment: %d of %d positions are outliers (> %.1f m)',
            (~inl).sum(),
            len(inl),
            o.gps_inlier_m,
        )
    return GpsAlignment(
        matrix=m,
        scale=scale,
        rms_m=float(np.sqrt(np.mean(res**2))),
        max_m=float(res.max()),
        inliers=np.array(used, dtype=np.int64)[inl],
        num_used=len(used),
    )


# -- entry point ----------------------------------------------------------------------------------
def register_images(
    images: Sequence[np.ndarray],
    *,
    camera: PinholeCamera | None = None,
    gps_enu: np.ndarray | None = None,
    workdir: Path | None = None,
    options: SfmOptions | None = None,
) -> SfmResult:
    """Register ``images`` (HxWx3 uint8 RGB, one size, capture order) by SfM; see module docstring.

    ``camera``: initial intrinsics of the images (size must match; focal and distortion are
    refined as ``options`` say), else COLMAP guesses f = 1.2 * max(W, H). ``gps_enu``: Nx3 ENU
    metres per image, NaN rows unknown. ``workdir``: folder to keep COLMAP's images, database and
    models in (its ``database.db`` is replaced); default a temporary folder, removed afterwards.

    Raises:
        SfmError: Fewer than 2 images, mixed sizes or shapes, a camera or GPS array that does not
            fit, or no reconstruction. Images left out of the model are flagged in
            ``SfmResult.registered`` and logged as a warning.

    """
    o = options or SfmOptions()
    _, _, gps = _check_inputs(images, camera, gps_enu)
    timing: dict[str, float] = {}
    t_start = t0 = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal t0
        t1 = time.perf_counter()
        timing[stage] = t1 - t0
        t0 = t1

    tmp: str | None = None
    if workdir is not None:
        root = Path(workdir)
    else:
        tmp = tempfile.mkdtemp(prefix='ibr_sfm_')
        root = Path(tmp)
    old_level = pycolmap.logging.minloglevel
    if not o.verbose:
        pycolmap.logging.minloglevel = max(old_level, 2)  # errors only
    try:
        root.mkdir(parents=True, exist_ok=True)
        db_path, image_dir = root / _DB, root / 'images'
        for suffix in ('', '-wal', '-shm'):
            Path(f'{db_path}{suffix}').unlink(missing_ok=True)
        shutil.rmtree(root / 'sparse', ignore_errors=True)
        names = _write_images(images, image_dir)
        lap('write')

        pycolmap.set_random_seed(o.seed)
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = o.camera_model
        if camera is not None:
            reader.camera_params = _camera_params(camera, o.camera_model)
        ext = pycolmap.FeatureExtractionOptions()
        ext.max_image_size = o.max_image_size
        ext.num_threads = o.num_threads
        ext.sift.max_num_features = o.max_num_features
        ext.sift.first_octave = o.first_octave
        pycolmap.extract_features(
            db_path,
            image_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=ext,
            device=pycolmap.Device.cpu,
        )
        if gps is not None and len(names) > o.exhaustive_max_images:
            _write_pose_priors(db_path, names, gps)
        lap('extract')

        matching = _match(db_path, len(names), gps, o)
        lap('match')

        rec = _map(db_path, image_dir, root / 'sparse', o)
        if rec is None or rec.num_reg_images() < 2:
            raise SfmError(
                f'no reconstruction from {len(names)} images ({matching} matching): too few matches; '
                'check that the images overlap and are in focus'
            )
        if camera is not None and o.refine_focal_length and o.prior_focal_tolerance is not None:
            rec = _prefer_prior_focal(rec, camera, o)
        lap('map')

        alignment = _align(rec, names, gps, o) if gps is not None else None
        result = _convert(rec, names, o.camera_model, matching)
        lap('align_convert')
    finally:
        pycolmap.logging.minloglevel = old_level
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    timing['total'] = time.perf_counter() - t_start

    if result.num_registered < len(names):
        missing = np.flatnonzero(~result.registered).tolist()
        LOG.warning('%d of %d images not registered: %s', len(missing), len(names), missing)
    return replace(result, metric=alignment is not None, alignment=alignment, timing=timing)
