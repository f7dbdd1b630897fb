# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``sensor_msgs/CompressedImage`` <-> numpy, following image_transport_plugins conventions.

``compressed`` transport: ``format`` is ``'<encoding>; <jpeg|png> compressed <bgr8|mono8>'``
(older publishers wrote just ``'jpeg'`` / ``'png'``, meaning BGR or mono data).
``compressedDepth`` transport: ``format`` is ``'<16UC1|32FC1>; compressedDepth png'`` (older:
``'...; compressedDepth'`` or no ``';'`` at all, both PNG) and ``data`` is a 12-byte ConfigHeader
(int32 format, float32 depthParam[2], little-endian) followed by a 16-bit PNG. ``16UC1`` stores
millimetres as they are; ``32FC1`` stores quantized inverse depth
``q = uint16(depthQuantA / depth + depthQuantB)`` (0 = invalid) with
``depthQuantA = z0 * (z0 + 1)`` and ``depthQuantB = 1 - depthQuantA / depth_max``
(z0 = depth_quantization), all in float32 as in compressed_depth_image_transport's codec.cpp.
The ``rvl`` variant is not supported.
"""

from __future__ import annotations

import struct
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from msg_utils.errors import MessageError
from msg_utils.flavor import Flavor, coerce_header, new_message
from msg_utils.image import image_to_rgb, message_data, set_uint8_data

__all__ = [
    'camera_image_to_rgb',
    'compressed_image_to_numpy',
    'numpy_to_compressed_depth',
    'numpy_to_compressed_image',
]

_COLOR = ('rgb8', 'bgr8', 'rgba8', 'bgra8', 'rgb16', 'bgr16', 'rgba16', 'bgra16')
_CONFIG = struct.Struct('<iff')  # compressionFormat (INV_DEPTH = 0), depthParam[2]
_INV_DEPTH = 0
_MAX_U16 = 65535


def compressed_image_to_numpy(msg: Any) -> NDArray[Any]:
    """Decode a ``sensor_msgs/CompressedImage`` of either flavour.

    Colour images give HxWx3 RGB (alpha dropped), mono images HxW, uint8 for 8-bit data.
    ``compressedDepth`` messages give HxW uint16 millimetres for ``16UC1`` and HxW float32
    metres for ``32FC1``, where invalid pixels (q = 0, NaN in the ROS codec) are 0 = unknown.
    Raises MessageError naming ``CompressedImage.format`` or ``CompressedImage.data``.
    """
    fmt = str(msg.format)
    if 'compressedDepth' in fmt:
        return _decode_depth(fmt, message_data(msg))
    image = _imdecode(message_data(msg), fmt)
    if image.ndim == 2:
        return image
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise MessageError(f'CompressedImage.data decodes to an unsupported shape {image.shape}')
    if _stored_as_bgr(fmt):
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGB)
    return np.ascontiguousarray(image[:, :, :3])


def camera_image_to_rgb(msg: Any) -> NDArray[np.uint8]:
    """C-contiguous HxWx3 uint8 RGB of a camera frame: an 8-bit colour or mono ``Image``
    (:func:`~msg_utils.image.image_to_rgb`) or a ``CompressedImage`` (:func:`compressed_image_to_numpy`);
    mono is replicated. A ``compressedDepth`` or 16-bit frame raises MessageError naming its format."""
    if hasattr(msg, 'format'):  # CompressedImage (Image has no such field)
        rgb = compressed_image_to_numpy(msg)
        if rgb.dtype != np.uint8:
            raise MessageError(f'CompressedImage.format {msg.format!r} is not an 8-bit camera image')
    else:
        rgb = image_to_rgb(msg)
    return np.ascontiguousarray(np.repeat(rgb[..., None], 3, axis=2) if rgb.ndim == 2 else rgb)


def _stored_as_bgr(fmt: str) -> bool:
    """Channel order of the decoded pixels as compressed_image_transport's subscriber reads it."""
    encoding, sep, rest = fmt.partition(';')
    return not sep or encoding.strip() not in _COLOR or 'compressed bgr' in rest


def _imdecode(data: NDArray[np.uint8], fmt: str) -> NDArray[Any]:
    image = None
    if data.size:
        try:
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        except cv2.error:
            image = None
    if image is None:
        raise MessageError(f'CompressedImage.data ({data.size} bytes) cannot be decoded (format {fmt!r})')
    return image


def _decode_depth(fmt: str, data: NDArray[np.uint8]) -> NDArray[Any]:
    encoding, sep, rest = fmt.partition(';')
    encoding = encoding.strip()
    if sep and 'compressedDepth png' not in rest and 'compressedDepth ' in rest:
        raise MessageError(
            f'CompressedImage.format {fmt!r}: only the png compressedDepth variant is supported'
        )
    if encoding not in ('16UC1', 'mono16', '32FC1'):
        raise MessageError(f'CompressedImage.format {fmt!r}: depth encoding must be 16UC1 or 32FC1')
    if data.size <= _CONFIG.size:
        raise MessageError(
            f'CompressedImage.data has {data.size} bytes, too short for the {_CONFIG.size}-byte '
            'compressedDepth header and a PNG'
        )
    _, quant_a, quant_b = _CONFIG.unpack(data[: _CONFIG.size].tobytes())
    q = _imdecode(data[_CONFIG.size :], fmt)
    if q.ndim != 2 or q.dtype != np.uint16:
        raise MessageError(
            f'CompressedImage.data holds a {q.dtype} image of shape {q.shape}, expected 16-bit mono'
        )
    if encoding != '32FC1':
        return q
    a, b = np.float32(quant_a), np.float32(quant_b)
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = a / (q.astype(np.float32) - b)
    return np.where((q != 0) & (depth > 0), depth, np.float32(0)).astype(np.float32, copy=False)


def _to_data(encoded: NDArray[np.uint8], fmt: str, header: Any, flavor: Flavor) -> Any:
    msg = new_message(
        'sensor_msgs/msg/CompressedImage', flavor, header=coerce_header(header, flavor), format=fmt
    )
    return set_uint8_data(msg, np.ascontiguousarray(encoded))


def _imencode(ext: str, image: NDArray[Any], params: list[int]) -> NDArray[np.uint8]:
    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise MessageError(f'cv2.imencode({ext!r}) failed for an image of shape {image.shape}')
    return buf


def numpy_to_compressed_image(
    image: ArrayLike,
    fmt: Literal['jpeg', 'png'] = 'jpeg',
    *,
    encoding: Literal['rgb8', 'bgr8', 'mono8'] = 'rgb8',
    quality: int = 90,
    png_level: int = 3,
    header: Any = None,
    flavor: Flavor = 'rclpy',
) -> Any:
    """Compress an 8-bit image into a ``sensor_msgs/CompressedImage`` (``compressed`` transport).

    ``image`` is HxWx3 in ``encoding``'s channel order (rgb8 or bgr8) or HxW for mono8.
    ``quality`` (1..100) is the JPEG quality, ``png_level`` (0..9) the PNG compression level
    (image_transport's default is 3). The format string is written as image_transport does,
    e.g. ``'rgb8; jpeg compressed bgr8'`` or ``'mono8; png compressed mono8'``.
    """
    a = np.asarray(image)
    if fmt not in ('jpeg', 'png'):
        raise MessageError(f"fmt must be 'jpeg' or 'png', got {fmt!r}")
    if encoding not in ('rgb8', 'bgr8', 'mono8'):
        raise MessageError(f"encoding must be 'rgb8', 'bgr8' or 'mono8', got {encoding!r}")
    mono = encoding == 'mono8'
    if a.dtype != np.uint8 or (a.ndim != 2 if mono else a.ndim != 3 or a.shape[2] != 3):
        want = 'HxW' if mono else 'HxWx3'
        raise MessageError(f'encoding {encoding!r} needs a {want} uint8 array, got {a.dtype} {a.shape}')
    if encoding == 'rgb8':
        a = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2BGR)
    if fmt == 'jpeg':
        params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    else:
        params = [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)]
    buf = _imencode('.jpg' if fmt == 'jpeg' else '.png', a, params)
    target = 'mono8' if mono else 'bgr8'
    return _to_data(buf, f'{encoding}; {fmt} compressed {target}', header, flavor)


def numpy_to_compressed_depth(
    depth: ArrayLike,
    *,
    encoding: Literal['16UC1', '32FC1'] = '16UC1',
    depth_max: float = 10.0,
    depth_quantization: float = 100.0,
    png_level: int = 9,
    header: Any = None,
    flavor: Flavor = 'rclpy',
) -> Any:
    """Compress a depth image into a ``compressedDepth png`` CompressedImage (defaults as the plugin).

    ``16UC1``: HxW uint16 millimetres; values above ``depth_max * 1000`` mm become 0 (the plugin's
    max-depth filter; pass ``depth_max=65.535`` to keep all). ``32FC1``: HxW float32 metres,
    quantized as inverse depth (see module docstring); depths >= ``depth_max``, NaN, 0 and +inf
    become invalid, and so do depths so small that q would exceed 65535 (below
    ``depthQuantA / (65535 - depthQuantB)``, 0.152 m with the defaults), which the C++ codec
    leaves undefined. Decoded depth error grows with depth: about ``depth**2 / depthQuantA`` m.
    """
    d = np.asarray(depth)
    if encoding not in ('16UC1', '32FC1'):
        raise MessageError(f"encoding must be '16UC1' or '32FC1', got {encoding!r}")
    want = np.uint16 if encoding == '16UC1' else np.float32
    if d.ndim != 2 or d.dtype != want:
        raise MessageError(
            f'encoding {encoding!r} needs an HxW {np.dtype(want)} array, got {d.dtype} {d.shape}'
        )
    params = [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)]
    if encoding == '16UC1':
        limit = min(int(depth_max * 1000.0), _MAX_U16)
        q = np.where(d > limit, np.uint16(0), d)
        config = _CONFIG.pack(_INV_DEPTH, 0.0, 0.0)
    else:
        z0, dmax = np.float32(depth_quantization), np.float32(depth_max)
        a = np.float32(z0 * (z0 + np.float32(1)))
        b = np.float32(np.float32(1) - a / dmax)
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            qf = a / d + b
            valid = (d < dmax) & (qf >= 0) & (qf < _MAX_U16 + 1)
        q = np.where(valid, qf, np.float32(0)).astype(np.uint16)
        config = _CONFIG.pack(_INV_DEPTH, float(a), float(b))
    png = _imencode('.png', np.ascontiguousarray(q), params)
    data = np.concatenate([np.frombuffer(config, np.uint8), png.reshape(-1)])
    return _to_data(data, f'{encoding}; compressedDepth png', header, flavor)
