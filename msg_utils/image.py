# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``sensor_msgs/Image`` <-> numpy, and depth conventions (REP-118).

Arrays are HxW for 1-channel encodings and HxWxC otherwise, in the message's channel order
(``bgr8`` stays BGR). Depth: ``16UC1`` holds millimetres (0 = unknown), ``32FC1`` metres
(NaN = unknown, +inf = too far). Internally ibr_ros uses float32 metres with 0 = unknown and
+inf = infinitely far (e.g. sky).
"""

from __future__ import annotations

import array
import sys
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, coerce_header, is_rosbags_message, new_message

__all__ = [
    'ENCODINGS',
    'depth_image_to_m',
    'depth_m_to_image',
    'depth_m_to_mm',
    'depth_mm_to_m',
    'image_to_numpy',
    'image_to_rgb',
    'message_data',
    'numpy_to_image',
    'set_uint8_data',
]

# encoding -> (dtype, channels)
ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    'rgb8': (np.dtype(np.uint8), 3),
    'bgr8': (np.dtype(np.uint8), 3),
    'rgba8': (np.dtype(np.uint8), 4),
    'bgra8': (np.dtype(np.uint8), 4),
    'mono8': (np.dtype(np.uint8), 1),
    'mono16': (np.dtype(np.uint16), 1),
    '8UC1': (np.dtype(np.uint8), 1),
    '8UC3': (np.dtype(np.uint8), 3),
    '16UC1': (np.dtype(np.uint16), 1),
    '32FC1': (np.dtype(np.float32), 1),
    '64FC1': (np.dtype(np.float64), 1),
}
_BIG_ENDIAN_HOST = sys.byteorder == 'big'
_TO_RGB = {'bgr8': cv2.COLOR_BGR2RGB, 'rgba8': cv2.COLOR_RGBA2RGB, 'bgra8': cv2.COLOR_BGRA2RGB}
_MAX_MM = 65535


def _encoding(name: str, field: str = 'Image.encoding') -> tuple[np.dtype, int]:
    try:
        return ENCODINGS[name]
    except KeyError:
        raise MessageError(f'{field} {name!r} is not supported (use one of {sorted(ENCODINGS)})') from None


def message_data(msg: Any) -> NDArray[np.uint8]:
    """The ``data`` field of a message of either flavour as a flat uint8 array (zero-copy if possible)."""
    data = msg.data
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8) if data.dtype.itemsize == 1 else data.astype(np.uint8)
    if isinstance(data, (array.array, bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


def set_uint8_data(msg: Any, buf: NDArray[Any]) -> Any:
    """Set ``msg.data`` (a ``uint8[]`` field) to a copy of the bytes of C-contiguous ``buf``; return msg.

    rosbags: a new 1-D uint8 numpy array. rclpy: a new ``array.array('B')`` stored in the
    private ``_data`` slot, because the generated setter copies its argument once more
    (``array.array('B', value)``) unless ROS_PYTHON_CHECK_FIELDS=1: one 6 MB copy instead of two.
    """
    raw = buf.reshape(-1).view(np.uint8)
    if is_rosbags_message(msg):
        msg.data = raw.copy()
        return msg
    out = array.array('B')
    out.frombytes(raw.data)
    msg._data = out
    return msg


def image_to_numpy(msg: Any) -> NDArray[Any]:
    """Pixels of a ``sensor_msgs/Image`` (either flavour) as a read-only array.

    HxW for 1-channel encodings, HxWxC otherwise, channel order as in the message. Zero-copy
    view of ``msg.data`` (rows may be strided when ``step`` has padding) unless ``is_bigendian``
    differs from this machine, then a byte-swapped copy. Use ``.copy()`` to get a writable array.
    Raises MessageError for unknown encodings and inconsistent ``step``/``data`` sizes.
    """
    dtype, channels = _encoding(msg.encoding)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * dtype.itemsize
    if step < row:
        raise MessageError(f'Image.step {step} is smaller than width*{channels * dtype.itemsize} = {row}')
    data = message_data(msg)
    if data.size != step * h:
        raise MessageError(
            f'Image.data has {data.size} bytes, expected step*height = {step}*{h} = {step * h}'
        )
    shape = (h, w) if channels == 1 else (h, w, channels)
    if h == 0 or w == 0:
        out = np.zeros(shape, dtype)
    else:
        out = data.reshape(h, step)[:, :row].view(dtype).reshape(shape)
        if dtype.itemsize > 1 and bool(msg.is_bigendian) != _BIG_ENDIAN_HOST:
            out = out.byteswap()
    out.flags.writeable = False
    return out


def numpy_to_image(array_: ArrayLike, encoding: str, header: Any = None, *, flavor: Flavor = 'rclpy') -> Any:
    """A ``sensor_msgs/Image`` holding a copy of ``array_`` (HxW or HxWxC, dtype of ``encoding``).

    The message is packed (``step = width * bytes per pixel``) in this machine's byte order.
    ``header`` may be of either flavour (default: stamp 0, empty frame_id). The array's dtype
    must match the encoding exactly (e.g. float32 for ``32FC1``); no channel reordering is done.
    """
    dtype, channels = _encoding(encoding, 'encoding')
    a = np.asarray(array_)
    shape_ok = (a.ndim == 3 and a.shape[2] == channels) or (a.ndim == 2 and channels == 1)
    if not shape_ok:
        raise MessageError(
            f'encoding {encoding!r} needs {"HxW" if channels == 1 else f"HxWx{channels}"}, got {a.shape}'
        )
    if a.dtype.newbyteorder('=') != dtype:
        raise MessageError(f'encoding {encoding!r} needs dtype {dtype}, got {a.dtype}')
    buf = np.ascontiguousarray(a, dtype=dtype)
    h, w = a.shape[:2]
    msg = new_message(
        'sensor_msgs/msg/Image',
        flavor,
        header=coerce_header(header, flavor),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(_BIG_ENDIAN_HOST),
        step=w * channels * dtype.itemsize,
    )
    return set_uint8_data(msg, buf)


def image_to_rgb(msg: Any) -> NDArray[np.uint8]:
    """HxWx3 uint8 RGB of an 8-bit colour or mono Image (rgb8, bgr8, rgba8, bgra8, mono8, 8UC1).

    Alpha is dropped and mono is replicated. ``rgb8`` gives the read-only zero-copy view of
    :func:`image_to_numpy`; other encodings give a new array. ``8UC3`` is refused: its channel
    order is not defined.
    """
    if msg.encoding not in ('rgb8', 'mono8', '8UC1') and msg.encoding not in _TO_RGB:
        raise MessageError(
            f'Image.encoding {msg.encoding!r} cannot be converted to RGB '
            '(use rgb8, bgr8, rgba8, bgra8, mono8 or 8UC1, or image_to_numpy)'
        )
    a = image_to_numpy(msg)
    if msg.encoding == 'rgb8':
        return a
    # cv2's stubs give no dtypes: cvtColor keeps uint8.
    if a.ndim == 2:
        rgb = np.repeat(a[:, :, None], 3, axis=2) if a.size == 0 else cv2.cvtColor(a, cv2.COLOR_GRAY2RGB)
    else:
        rgb = a[..., :3][..., ::-1].copy() if a.size == 0 else cv2.cvtColor(a, _TO_RGB[msg.encoding])
    return cast('NDArray[np.uint8]', rgb)


def depth_mm_to_m(depth_mm: ArrayLike) -> NDArray[np.float32]:
    """float32 metres of unsigned integer millimetres (REP-118 ``16UC1``); 0 mm (unknown) -> 0.0 m."""
    mm = np.asarray(depth_mm)
    if mm.dtype.kind != 'u':
        raise MessageError(f'depth in millimetres must be an unsigned integer array, got dtype {mm.dtype}')
    return mm.astype(np.float32) / np.float32(1000.0)


def depth_m_to_mm(depth_m: ArrayLike) -> NDArray[np.uint16]:
    """uint16 millimetres (REP-118 ``16UC1``) of metres, rounded to the nearest millimetre.

    Depths that ``16UC1`` cannot hold become 0 (= unknown): NaN, 0, negative, +-inf (too far
    is unknown in millimetres), values that round to 0 mm (< 0.5 mm) and values above 65.535 m
    (that round above 65535 mm).
    """
    m = np.asarray(depth_m, dtype=np.float64)
    with np.errstate(invalid='ignore', over='ignore'):
        mm = np.rint(m * 1000.0)
        ok = np.isfinite(mm) & (mm > 0) & (mm <= _MAX_MM)
    return np.where(ok, mm, 0).astype(np.uint16)


def depth_m_to_image(depth_m: ArrayLike, header: Any = None, *, flavor: Flavor = 'rclpy') -> Any:
    """``32FC1`` Image of HxW depth in metres; values that are not > 0 (0, negative, NaN) become NaN
    (REP-118 unknown), +inf stays (far). The inverse of :func:`depth_image_to_m`."""
    d = np.asarray(depth_m, dtype=np.float32)
    with np.errstate(invalid='ignore'):
        d = np.where(d > 0, d, np.float32(np.nan)).astype(np.float32, copy=False)
    return numpy_to_image(d, '32FC1', header, flavor=flavor)


def confidence_to_image(confidence: ArrayLike, header: Any = None, *, flavor: Flavor = 'rclpy') -> Any:
    """``32FC1`` Image of an HxW depth confidence in [0, 1] (0 where the depth is unknown).

    ValueError (MessageError) naming the value when it is not finite or outside [0, 1].
    """
    c = np.asarray(confidence, dtype=np.float32)
    if c.ndim != 2:
        raise MessageError(f'confidence must be HxW, got shape {c.shape}')
    if c.size and not (np.isfinite(c).all() and c.min() >= 0.0 and c.max() <= 1.0):
        bad = c[~(np.isfinite(c) & (c >= 0) & (c <= 1))][0]
        raise MessageError(f'confidence must be finite and in [0, 1], got {float(bad)!r}')
    return numpy_to_image(c, '32FC1', header, flavor=flavor)


def image_to_confidence(msg: Any) -> NDArray[np.float32]:
    """HxW float32 confidence in [0, 1] of a ``32FC1`` Image (NaN becomes 0; values are clipped)."""
    if msg.encoding != '32FC1':
        raise MessageError(f'Image.encoding {msg.encoding!r}: a depth confidence is 32FC1')
    c = image_to_numpy(msg)
    return np.clip(np.nan_to_num(c, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)


def depth_image_to_m(msg: Any) -> NDArray[np.float32]:
    """HxW float32 metres (0 = unknown, +inf = far) of a ``16UC1`` (mm) or ``32FC1`` (m) Image.

    ``32FC1``: NaN, negative values and -inf (REP-118 "too close") become 0; +inf is kept.
    """
    if msg.encoding == '16UC1':
        return depth_mm_to_m(image_to_numpy(msg))
    if msg.encoding != '32FC1':
        raise MessageError(f'Image.encoding {msg.encoding!r} is not a depth encoding (use 16UC1 or 32FC1)')
    d = image_to_numpy(msg)
    with np.errstate(invalid='ignore'):
        return np.where(d >= 0, d, np.float32(0)).astype(np.float32, copy=False)
