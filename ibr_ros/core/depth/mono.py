# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Monocular depth: ONNX models with explicit I/O conventions, and a geometric ground-plane prior.

Every backend produces the paper's G(x) (Section III-A): ``uint16`` 0..65535, larger = nearer, 0 for
pixels with no finite prediction (sky / infinitely far). G is only a *relative* ordering; the
per-view lookup table of :mod:`ibr_ros.core.depth.remap` gives it the MVS scale.

ONNX I/O convention (:class:`MonoModelSpec`): the RGB uint8 image is resized to the model input,
scaled to [0, 1], normalised ``(x - mean) / std`` per channel, laid out NCHW or NHWC in RGB or BGR
order, and given to the model's first input as float32 with batch 1. The first output (any of
1xHxW, 1x1xHxW, HxW, 1xHxWx1) is resized back to the image size (bilinear) and interpreted as
``inverse_depth`` (MiDaS / DPT / Depth-Anything: relative disparity, larger = nearer), ``depth``
(larger = farther) or ``log_depth`` (MegaDepth: log of depth up to scale).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.depth.onnx import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    MonoModelError,
    onnx_session,
    to_input_tensor,
)
from ibr_ros.core.geometry.camera import PinholeCamera

__all__ = [
    'PRESETS',
    'GroundPlanePrior',
    'MonoModelError',
    'MonoModelSpec',
    'OnnxMonoDepth',
    'nearness_to_g',
]

LOG = logging.getLogger(__name__)

OutputKind = Literal['inverse_depth', 'depth', 'log_depth']


@dataclass(frozen=True)
class MonoModelSpec:
    """How to feed an ONNX depth model and read its output (see module docstring).

    ``input_size`` ``(width, height)`` fixes the model input; when ``None`` the image is resized so
    that its longer side is ``max_side`` and both sides are multiples of ``multiple_of``.
    ``flip_average``: also run the mirrored image and average the two outputs (test-time
    augmentation: twice the inference time, less noise in the ranking of far regions).
    """

    path: Path | None = None
    input_size: tuple[int, int] | None = None
    max_side: int = 384
    multiple_of: int = 32
    layout: Literal['NCHW', 'NHWC'] = 'NCHW'
    color_order: Literal['RGB', 'BGR'] = 'RGB'
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    output: OutputKind = 'inverse_depth'
    threads: int = 1
    flip_average: bool = False

    def __post_init__(self) -> None:
        if self.layout not in ('NCHW', 'NHWC'):
            raise MonoModelError(f'layout must be NCHW or NHWC, got {self.layout!r}')
        if self.color_order not in ('RGB', 'BGR'):
            raise MonoModelError(f'color_order must be RGB or BGR, got {self.color_order!r}')
        if self.output not in ('inverse_depth', 'depth', 'log_depth'):
            raise MonoModelError(f'output must be inverse_depth, depth or log_depth, got {self.output!r}')
        if any(s <= 0 for s in self.std):
            raise MonoModelError(f'std must be positive, got {self.std}')
        if self.multiple_of < 1 or self.max_side < self.multiple_of:
            raise MonoModelError(
                f'need 1 <= multiple_of <= max_side, got {self.multiple_of}, {self.max_side}'
            )

    def model_size(self, width: int, height: int) -> tuple[int, int]:
        """Model input ``(width, height)`` for an image of ``width`` x ``height`` pixels."""
        if self.input_size is not None:
            return self.input_size
        s = self.max_side / max(width, height)
        m = self.multiple_of
        return max(m, round(width * s / m) * m), max(m, round(height * s / m) * m)


#: Conventions of well-known models (give ``path`` with :func:`dataclasses.replace`).
PRESETS: dict[str, MonoModelSpec] = {
    # MiDaS v2.1 small: 256x256, ImageNet normalisation, relative inverse depth.
    'midas_v21_small': MonoModelSpec(
        input_size=(256, 256), mean=IMAGENET_MEAN, std=IMAGENET_STD, output='inverse_depth'
    ),
    # DPT / Depth-Anything-V2: sides multiple of 14 (518 on the long side), ImageNet normalisation.
    'depth_anything_v2': MonoModelSpec(
        max_side=518, multiple_of=14, mean=IMAGENET_MEAN, std=IMAGENET_STD, output='inverse_depth'
    ),
    'dpt': MonoModelSpec(
        input_size=(384, 384), mean=(0.5, 0.5, 0.5), std=(0.5, 0.5, 0.5), output='inverse_depth'
    ),
    # MegaDepth (hourglass): 512x384 input in [0, 1], output log depth.
    'megadepth': MonoModelSpec(input_size=(512, 384), output='log_depth'),
    # The model shipped with ibr_ros (see ibr_ros/models/README.md): trained at 256x160, any size
    # with sides multiple of 32 works; its training scale (long side 256) gives the best results.
    'ibr_mono': MonoModelSpec(
        max_side=256, multiple_of=32, mean=IMAGENET_MEAN, std=IMAGENET_STD, flip_average=True
    ),
}


def nearness_to_g(
    nearness: NDArray[np.floating], valid: NDArray[np.bool_] | None = None
) -> NDArray[np.uint16]:
    """Map a relative nearness map (larger = nearer) linearly onto G = 1..65535; invalid pixels -> 0.

    The 0.1th and 99.9th percentiles of the valid values map to 1 and 65535 (values beyond are
    clipped), so a few outliers do not squeeze the 256 LUT levels.
    """
    x = np.asarray(nearness, dtype=np.float64)
    ok = np.isfinite(x) if valid is None else (np.asarray(valid, bool) & np.isfinite(x))
    g = np.zeros(x.shape, np.uint16)
    if not ok.any():
        return g
    vals = x[ok]
    sample = vals[:: max(1, vals.size // 200_000)]  # percentiles of a subsample: same to ~0.01%
    lo, hi = np.percentile(sample, [0.1, 99.9])
    if hi <= lo:
        g[ok] = 32768
        return g
    scaled = 1.0 + (np.clip(vals, lo, hi) - lo) * (65534.0 / (hi - lo))
    g[ok] = np.rint(scaled).astype(np.uint16)
    return g


class OnnxMonoDepth:
    """Monocular depth from an ONNX model with onnxruntime on the CPU."""

    def __init__(self, spec: MonoModelSpec) -> None:
        self.session = onnx_session(spec.path, spec.threads)
        self.spec = spec
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = list(inp.shape)
        if len(shape) != 4:
            raise MonoModelError(f'{spec.path}: input {inp.name!r} has shape {shape}, expected 4-D')
        fixed = shape[2:4] if spec.layout == 'NCHW' else shape[1:3]
        if all(isinstance(s, int) for s in fixed) and spec.input_size is None:
            self.spec = replace(spec, input_size=(int(fixed[1]), int(fixed[0])))

    def preprocess(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """The model input tensor for an RGB uint8 image."""
        h, w = rgb.shape[:2]
        mw, mh = self.spec.model_size(w, h)
        interpolation = cv2.INTER_AREA if mw < w else cv2.INTER_LINEAR
        x = cast('NDArray[np.uint8]', cv2.resize(rgb, (mw, mh), interpolation=interpolation))  # keeps uint8
        s = self.spec
        return to_input_tensor(x, s.color_order, s.mean, s.std, s.layout)

    def predict_nearness(self, rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Relative nearness (larger = nearer) at the image size; NaN where the model gives none."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f'rgb must be uint8 HxWx3, got {rgb.dtype} {rgb.shape}')
        x = self.preprocess(rgb)
        out = self._run(x)
        if self.spec.flip_average:
            w_axis = 3 if self.spec.layout == 'NCHW' else 2
            out = 0.5 * (out + self._run(np.ascontiguousarray(np.flip(x, w_axis)))[:, ::-1])
        size = (rgb.shape[1], rgb.shape[0])
        # cv2's stubs give no dtypes: resize keeps float32.
        out = cast('NDArray[np.float32]', cv2.resize(out, size, interpolation=cv2.INTER_LINEAR))
        if self.spec.output == 'inverse_depth':
            return out
        with np.errstate(divide='ignore', invalid='ignore'):
            if self.spec.output == 'depth':
                return np.where(out > 0, 1.0 / out, np.nan).astype(np.float32)
            return (-out).astype(np.float32)  # log depth: -log d orders like 1/d

    def _run(self, x: NDArray[np.float32]) -> NDArray[np.float32]:
        out = np.squeeze(np.asarray(self.session.run(None, {self.input_name: x})[0], dtype=np.float32))
        if out.ndim != 2:
            raise MonoModelError(f'{self.spec.path}: output has shape {out.shape}, expected one HxW map')
        return out

    def predict_g(self, rgb: NDArray[np.uint8]) -> NDArray[np.uint16]:
        """The paper's G(x) for an RGB image."""
        return nearness_to_g(self.predict_nearness(rgb))


@dataclass
class GroundPlanePrior:
    """Geometric monocular prior: depth of a world plane along each pixel ray, +inf above the horizon.

    Works out of the box without a learned model; fit the plane to sparse SfM or MVS points with
    :func:`fit_ground_plane`.
    """

    plane: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 1.0, 0.0]))

    def depth(self, camera: PinholeCamera, t_wc: NDArray[np.float64]) -> NDArray[np.float32]:
        """z-depth (m) of the plane for every pixel; +inf where the ray misses it (sky) or it is behind."""
        n, d = self.plane[:3], float(self.plane[3])
        a, b, c = t_wc[:3, :3].T @ n  # plane normal in the optical frame
        x = (np.arange(camera.width) - camera.cx) / camera.fx
        y = (np.arange(camera.height) - camera.cy) / camera.fy
        # Rays have z = 1, so the ray parameter at the plane is the z-depth.
        denom = (a * x[None, :] + b * y[:, None] + c).astype(np.float32)
        num = np.float32(-(n @ t_wc[:3, 3] + d))
        with np.errstate(divide='ignore', invalid='ignore'):
            z = num / denom
        z[~(z > 0) | ~np.isfinite(z)] = np.inf
        return z

    def predict_g(self, camera: PinholeCamera, t_wc: NDArray[np.float64]) -> NDArray[np.uint16]:
        """G(x) from the plane depth: nearness 1/z, 0 where the ray does not hit the plane."""
        z = self.depth(camera, t_wc)
        with np.errstate(divide='ignore'):
            near = 1.0 / z.astype(np.float64)
        return nearness_to_g(near, valid=np.isfinite(z))
