# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""ONNX model sessions and input tensors shared by the monocular depth and sky models (CPU only)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import onnxruntime as ort

__all__ = ['IMAGENET_MEAN', 'IMAGENET_STD', 'MonoModelError', 'onnx_session', 'to_input_tensor']

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class MonoModelError(ValueError):
    """A model file or specification that cannot be used."""


def onnx_session(path: Path | str | None, threads: int, what: str = 'model') -> ort.InferenceSession:
    """An onnxruntime CPU session of ``path`` with ``threads`` intra-op threads and one inter-op thread.

    Raises MonoModelError (naming ``what`` and the path) for a missing file or a model onnxruntime
    cannot load.
    """
    import onnxruntime as ort  # lazily: only callers with a model pay for the import

    if path is None or not Path(path).is_file():
        raise MonoModelError(f'{what} path {path} is not a file')
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    try:
        return ort.InferenceSession(str(path), opts, providers=['CPUExecutionProvider'])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise MonoModelError(f'{path}: cannot load ONNX model ({exc})') from exc


def to_input_tensor(
    resized: NDArray[np.uint8],
    color_order: Literal['RGB', 'BGR'],
    mean: tuple[float, float, float],
    std: tuple[float, float, float],
    layout: Literal['NCHW', 'NHWC'],
) -> NDArray[np.float32]:
    """A batch of one: an RGB uint8 image already at the model size, reordered, in [0, 1], normalised
    ``(x - mean) / std`` and laid out as ``layout``."""
    rgb = resized[..., ::-1] if color_order == 'BGR' else resized
    x = (rgb.astype(np.float32) / 255.0 - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    x = x.transpose(2, 0, 1) if layout == 'NCHW' else x
    return np.ascontiguousarray(x[None], dtype=np.float32)
