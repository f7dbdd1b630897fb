# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Sky: segmentation (ONNX model or geometric/photometric fallback), erosion and depth (Eq. 14).

The paper segments the sky with DeepLabv3+, erodes the mask with a disk of about 3% of the image
diagonal (to protect foreground at the sky boundary) and sets the sky depth to twice the largest
MVS depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.onnx import IMAGENET_MEAN, IMAGENET_STD, MonoModelError, onnx_session, to_input_tensor
from ibr_ros.core.geometry.camera import PinholeCamera

__all__ = [
    'SKY_PRESETS',
    'OnnxSkySegmenter',
    'SkySpec',
    'apply_sky_depth',
    'erode_sky',
    'horizon_mask',
    'sky_fallback',
]


@dataclass(frozen=True)
class SkySpec:
    """How to run an ONNX segmentation model and read the sky out of it.

    Input handling is as for :class:`ibr_ros.core.depth.mono.MonoModelSpec`. ``output`` is ``logits`` /
    ``probabilities`` (1xCxHxW, the sky is class ``sky_class``) or ``sky_logit`` (one channel,
    sigmoid > 0.5 = sky).
    """

    path: Path | None = None
    input_size: tuple[int, int] | None = (384, 224)
    layout: Literal['NCHW', 'NHWC'] = 'NCHW'
    color_order: Literal['RGB', 'BGR'] = 'RGB'
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    output: Literal['logits', 'probabilities', 'sky_logit'] = 'logits'
    sky_class: int = 0
    output_index: int = 0
    threads: int = 1


#: Conventions of known sky models (give ``path`` with :func:`dataclasses.replace`).
SKY_PRESETS: dict[str, SkySpec] = {
    # The model shipped with ibr_ros: its second output is a one-channel sky logit (trained at 256x160).
    'ibr_mono': SkySpec(input_size=(256, 160), output='sky_logit', output_index=1),
}


class OnnxSkySegmenter:
    """Sky mask from any ONNX segmentation model with a sky class (see :class:`SkySpec`)."""

    def __init__(self, spec: SkySpec) -> None:
        self.session = onnx_session(spec.path, spec.threads, 'sky model')
        self.spec = spec
        self.input_name = self.session.get_inputs()[0].name

    def predict(self, rgb: NDArray[np.uint8]) -> NDArray[np.bool_]:
        """Boolean HxW sky mask at the image size."""
        s = self.spec
        h, w = rgb.shape[:2]
        size = s.input_size or (w, h)
        resized = cast('NDArray[np.uint8]', cv2.resize(rgb, size, interpolation=cv2.INTER_AREA))  # uint8
        x = to_input_tensor(resized, s.color_order, s.mean, s.std, s.layout)
        out = np.asarray(self.session.run(None, {self.input_name: x})[s.output_index])
        out = out[0] if out.ndim == 4 else out
        if s.output == 'sky_logit':
            score = np.squeeze(out).astype(np.float32)
            sky_small = score > 0.0
        else:
            if out.ndim != 3:
                raise MonoModelError(f'{s.path}: segmentation output has shape {out.shape}, expected CxHxW')
            if not 0 <= s.sky_class < out.shape[0]:
                raise MonoModelError(f'sky_class {s.sky_class} out of range for {out.shape[0]} classes')
            sky_small = np.argmax(out, axis=0) == s.sky_class
        return cv2.resize(sky_small.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def horizon_mask(
    camera: PinholeCamera, t_wc: NDArray[np.float64], *, margin_deg: float = 0.0
) -> NDArray[np.bool_]:
    """Pixels whose viewing ray points above the horizontal plane (ENU z up) by more than ``margin_deg``."""
    x = (np.arange(camera.width) - camera.cx) / camera.fx
    y = (np.arange(camera.height) - camera.cy) / camera.fy
    r = t_wc[2, :3]  # world z of the optical axes
    up = r[0] * x[None, :] + r[1] * y[:, None] + r[2]
    norm = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1.0)
    return up > np.sin(np.radians(margin_deg)) * norm


def sky_fallback(
    rgb: NDArray[np.uint8],
    camera: PinholeCamera,
    t_wc: NDArray[np.float64],
    d_mvs: NDArray[np.float32],
    *,
    max_gradient: float = 12.0,
    min_brightness: float = 90.0,
    relative_brightness: float = 0.88,
) -> NDArray[np.bool_]:
    """Sky without a segmentation model: above the horizon, no MVS depth, bright and smooth.

    A pixel is sky when its ray is above the horizon, MVS found no depth within 1 px, its smoothed
    gray gradient magnitude is below ``max_gradient`` (0..255 units) and its gray level is at least
    ``min_brightness``; the result keeps only regions touching the image top or the horizon band.
    """
    above = horizon_mask(camera, t_wc)
    if not above.any():
        return above
    gray = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32), (5, 5), 1.5)
    grad = cv2.magnitude(cv2.Sobel(gray, cv2.CV_32F, 1, 0), cv2.Sobel(gray, cv2.CV_32F, 0, 1)) / 8.0
    known = (np.nan_to_num(d_mvs) > 0).astype(np.uint8)
    near_depth = cv2.dilate(known, np.ones((3, 3), np.uint8)) > 0
    cand = above & ~near_depth & (grad < max_gradient) & (gray >= min_brightness)
    if cand.any():  # the sky is the brightest smooth region: drop darker (hazy hill) candidates
        value = cv2.max(cv2.max(rgb[..., 0], rgb[..., 1]), rgb[..., 2])  # HSV value: blue sky is bright
        ref = float(np.percentile(value[cand], 95))
        if ref < float(np.percentile(value, 90)):
            return np.zeros_like(cand)  # nothing above the horizon is among the image's brightest
        cand &= value >= relative_brightness * ref
    n, labels = cv2.connectedComponents(cand.astype(np.uint8), connectivity=4)
    if n <= 1:
        return cand
    # Keep components that reach the top row or the top of the above-horizon region in their column.
    top_of_sky = np.argmax(above, axis=0)
    cols = np.arange(rgb.shape[1])
    seeds = set(labels[0][labels[0] > 0].tolist())
    has_sky_col = above.any(axis=0)
    seeds |= set(labels[top_of_sky[has_sky_col], cols[has_sky_col]].tolist()) - {0}
    keep = np.zeros(n, bool)
    keep[list(seeds)] = True
    return keep[labels]


def erode_sky(mask: NDArray[np.bool_], *, diag_fraction: float = 0.03) -> NDArray[np.bool_]:
    """Erode ``mask`` with a disk whose diameter is ``diag_fraction`` of the image diagonal (paper: 3%).

    Computed as "Euclidean distance to the nearest non-sky pixel > radius" (exact distance
    transform), which equals erosion by a disk and costs the same for any disk size. Outside the
    image counts as sky, so the mask does not shrink away from the image borders.
    """
    h, w = mask.shape
    radius = 0.5 * diag_fraction * float(np.hypot(h, w))
    if radius < 1.0 or not mask.any():
        return mask.copy()
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return dist > radius


def apply_sky_depth(
    d_fused: NDArray[np.float32], sky: NDArray[np.bool_], d_mvs: NDArray[np.float32]
) -> tuple[NDArray[np.float32], float]:
    """Eq. 14: sky pixels get ``2 * max(MVS depth)``; returns (final depth, sky depth in metres)."""
    if d_fused.shape != sky.shape or d_fused.shape != d_mvs.shape:
        raise ValueError(f'shapes differ: d_fused {d_fused.shape}, sky {sky.shape}, d_mvs {d_mvs.shape}')
    valid = np.isfinite(d_mvs) & (d_mvs > 0)
    if not valid.any():
        raise ValueError('d_mvs has no valid depth: the sky depth 2 * D_max is undefined')
    sky_depth = 2.0 * float(d_mvs[valid].max())
    out = d_fused.astype(np.float32, copy=True)
    out[sky] = sky_depth
    return out, sky_depth
