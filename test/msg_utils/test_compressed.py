# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.compressed: CompressedImage (compressed and compressedDepth transports)."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from msg_utils import (
    MessageError,
    compressed_image_to_numpy,
    is_rosbags_message,
    make_header,
    new_message,
    numpy_to_compressed_depth,
    numpy_to_compressed_image,
    stamp_to_ns,
)

FLAVORS = ('rclpy', 'rosbags')


def smooth_rgb(h: int = 48, w: int = 64) -> np.ndarray:
    """A smooth colour image (JPEG reproduces it to a few grey levels)."""
    v, u = np.mgrid[0:h, 0:w]
    return np.stack([u * 255 // (w - 1), v * 255 // (h - 1), np.full_like(u, 60)], axis=2).astype(np.uint8)


def compressed(fmt: str, data: bytes, flavor: str = 'rclpy'):
    value = np.frombuffer(data, np.uint8).copy() if flavor == 'rosbags' else data
    return new_message('sensor_msgs/msg/CompressedImage', flavor, format=fmt, data=value)


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('encoding', ['rgb8', 'bgr8'])
def test_png_colour_round_trip_is_exact_and_returns_rgb(encoding, flavor):
    rgb = np.random.default_rng(0).integers(0, 256, (7, 9, 3), dtype=np.uint8)
    image = rgb if encoding == 'rgb8' else rgb[..., ::-1]
    msg = numpy_to_compressed_image(
        image, 'png', encoding=encoding, header=make_header(9, 'cam', flavor), flavor=flavor
    )
    assert is_rosbags_message(msg) == (flavor == 'rosbags')
    assert msg.format == f'{encoding}; png compressed bgr8'
    assert (stamp_to_ns(msg.header.stamp), msg.header.frame_id) == (9, 'cam')
    out = compressed_image_to_numpy(msg)
    assert out.dtype == np.uint8
    assert np.array_equal(out, rgb)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_jpeg_round_trip_is_close(flavor):
    rgb = smooth_rgb()
    msg = numpy_to_compressed_image(rgb, quality=95, flavor=flavor)
    assert msg.format == 'rgb8; jpeg compressed bgr8'
    assert bytes(msg.data[:2]) == b'\xff\xd8'
    out = compressed_image_to_numpy(msg)
    assert out.shape == rgb.shape
    assert np.abs(out.astype(int) - rgb).mean() < 2.0


@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
def test_mono(fmt):
    mono = smooth_rgb()[..., 0]
    msg = numpy_to_compressed_image(mono, fmt, encoding='mono8')
    assert msg.format == f'mono8; {fmt} compressed mono8'
    out = compressed_image_to_numpy(msg)
    assert out.shape == mono.shape
    assert np.abs(out.astype(int) - mono).max() <= (0 if fmt == 'png' else 8)


@pytest.mark.parametrize(
    ('fmt', 'stored'),
    [
        ('jpeg', 'bgr'),  # old publishers: no encoding, OpenCV's BGR
        ('png', 'bgr'),
        ('bgr8; png compressed bgr8', 'bgr'),
        ('rgb8; png compressed bgr8', 'bgr'),
        ('rgb8; png compressed rgb8', 'rgb'),  # pixels were written in RGB order
        ('8UC3; png compressed bgr8', 'bgr'),
    ],
)
def test_channel_order_follows_the_format_string(fmt, stored):
    rgb = np.random.default_rng(1).integers(0, 256, (4, 5, 3), dtype=np.uint8)
    pixels = rgb[..., ::-1] if stored == 'bgr' else rgb
    data = cv2.imencode('.png', np.ascontiguousarray(pixels))[1].tobytes()
    assert np.array_equal(compressed_image_to_numpy(compressed(fmt, data)), rgb)


def test_png_with_alpha_drops_it():
    bgra = np.random.default_rng(2).integers(0, 256, (3, 4, 4), dtype=np.uint8)
    out = compressed_image_to_numpy(
        compressed('bgra8; png compressed bgra8', cv2.imencode('.png', bgra)[1].tobytes())
    )
    assert np.array_equal(out, bgra[..., 2::-1])


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('data', [b'', b'not an image at all', b'\xff\xd8\xff\xe0garbage'])
def test_corrupt_data_names_the_field(data, flavor):
    with pytest.raises(MessageError, match=r'CompressedImage\.data'):
        compressed_image_to_numpy(compressed('rgb8; jpeg compressed bgr8', data, flavor))


def test_encoder_argument_errors():
    with pytest.raises(MessageError, match="fmt must be 'jpeg' or 'png'"):
        numpy_to_compressed_image(smooth_rgb(), 'webp')
    with pytest.raises(MessageError, match="'mono8' needs a HxW uint8 array"):
        numpy_to_compressed_image(smooth_rgb(), encoding='mono8')
    with pytest.raises(MessageError, match="'rgb8' needs a HxWx3 uint8 array, got float32"):
        numpy_to_compressed_image(smooth_rgb().astype(np.float32))


# -- compressedDepth ---------------------------------------------------------------------------


def config(data) -> tuple[int, float, float]:
    return struct.unpack('<iff', bytes(data[:12]))


@pytest.mark.parametrize('flavor', FLAVORS)
def test_depth_16uc1_is_lossless_below_depth_max(flavor):
    mm = np.random.default_rng(3).integers(0, 12000, (6, 7), dtype=np.uint16)
    msg = numpy_to_compressed_depth(mm, header=make_header(4, 'depth', flavor), flavor=flavor)
    assert msg.format == '16UC1; compressedDepth png'
    assert config(msg.data) == (0, 0.0, 0.0)
    assert bytes(msg.data[12:20]) == b'\x89PNG\r\n\x1a\n'
    out = compressed_image_to_numpy(msg)
    assert out.dtype == np.uint16
    assert np.array_equal(out, np.where(mm > 10000, 0, mm))  # the plugin's max-depth filter
    all_kept = numpy_to_compressed_depth(mm, depth_max=65.535, flavor=flavor)
    assert np.array_equal(compressed_image_to_numpy(all_kept), mm)


def test_depth_32fc1_matches_the_plugin_quantization():
    # depthQuantA = 100 * 101 = 10100, depthQuantB = 1 - 10100 / 10 = -1009.
    depth = np.array([[1.0, 2.0, 0.5, 9.99], [10.0, np.nan, 0.0, 0.1]], np.float32)
    msg = numpy_to_compressed_depth(depth, encoding='32FC1')
    assert msg.format == '32FC1; compressedDepth png'
    assert config(msg.data) == (0, 10100.0, -1009.0)
    q = cv2.imdecode(np.frombuffer(bytes(msg.data[12:]), np.uint8), cv2.IMREAD_UNCHANGED)
    # q = uint16(A / d + B), truncated; >= depth_max, NaN and q > 65535 are invalid (0).
    assert q.tolist() == [[9091, 4041, 19191, 2], [0, 0, 0, 0]]
    out = compressed_image_to_numpy(msg)
    assert out.dtype == np.float32
    expected = np.float32(10100) / (q.astype(np.float32) + np.float32(1009))
    assert np.array_equal(out, np.where(q > 0, expected, 0))
    assert out[0, 0] == 1.0


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(1, 12),
    w=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
    depth_max=st.sampled_from([5.0, 10.0, 30.0]),
    quantization=st.sampled_from([50.0, 100.0, 200.0]),
    flavor=st.sampled_from(FLAVORS),
)
def test_depth_32fc1_round_trip_within_quantization_error(h, w, seed, depth_max, quantization, flavor):
    rng = np.random.default_rng(seed)
    a = np.float32(quantization * (quantization + 1))
    b = np.float32(1 - a / np.float32(depth_max))
    near = float(a / (65535 - b))  # smallest depth with q <= 65535
    depth = rng.uniform(near * 1.01, depth_max * 0.999, (h, w)).astype(np.float32)
    msg = numpy_to_compressed_depth(
        depth, encoding='32FC1', depth_max=depth_max, depth_quantization=quantization, flavor=flavor
    )
    out = compressed_image_to_numpy(msg)
    assert out.shape == (h, w)
    assert np.all(out > 0)
    # q = A / d + B is truncated, so decoded >= true, by less than one step d^2 / (A - d) metres.
    d = depth.astype(np.float64)
    err = out - d
    assert np.all(err >= -1e-6 * d)
    assert np.all(err <= d**2 / (float(a) - d) + 1e-6 * d)


def test_depth_32fc1_invalid_inputs_become_unknown():
    depth = np.array([[np.inf, -np.inf, -1.0, 0.05, 12.0, 3.0]], np.float32)
    out = compressed_image_to_numpy(numpy_to_compressed_depth(depth, encoding='32FC1'))
    assert out[0, :5].tolist() == [0.0] * 5
    assert out[0, 5] == pytest.approx(3.0, rel=1e-3)


@pytest.mark.parametrize(
    'fmt', ['16UC1; compressedDepth', '16UC1; compressedDepth png', 'mono16; compressedDepth']
)
def test_depth_legacy_format_strings(fmt):
    mm = np.arange(12, dtype=np.uint16).reshape(3, 4) * 100
    data = struct.pack('<iff', 0, 0, 0) + cv2.imencode('.png', mm)[1].tobytes()
    assert np.array_equal(compressed_image_to_numpy(compressed(fmt, data)), mm)


@pytest.mark.parametrize(
    ('fmt', 'data', 'match'),
    [
        ('16UC1; compressedDepth rvl', b'\0' * 40, r'CompressedImage\.format .*only the png compressedDepth'),
        ('rgb8; compressedDepth png', b'\0' * 40, r'CompressedImage\.format .*16UC1 or 32FC1'),
        ('16UC1; compressedDepth png', b'\0' * 12, r'CompressedImage\.data has 12 bytes, too short'),
        (
            '32FC1; compressedDepth png',
            b'\0' * 12 + b'garbage',
            r'CompressedImage\.data \(7 bytes\) cannot be decoded',
        ),
    ],
)
def test_depth_errors(fmt, data, match):
    with pytest.raises(MessageError, match=match):
        compressed_image_to_numpy(compressed(fmt, data))


def test_depth_png_that_is_not_16_bit():
    data = struct.pack('<iff', 0, 0, 0) + cv2.imencode('.png', np.zeros((2, 2), np.uint8))[1].tobytes()
    with pytest.raises(MessageError, match='expected 16-bit mono'):
        compressed_image_to_numpy(compressed('16UC1; compressedDepth png', data))


def test_depth_encoder_argument_errors():
    with pytest.raises(MessageError, match="'32FC1' needs an HxW float32 array, got float64"):
        numpy_to_compressed_depth(np.zeros((2, 2)), encoding='32FC1')
    with pytest.raises(MessageError, match="encoding must be '16UC1' or '32FC1'"):
        numpy_to_compressed_depth(np.zeros((2, 2), np.uint16), encoding='mono16')


@pytest.mark.parametrize('flavor', ['rclpy', 'rosbags'])
def test_camera_image_to_rgb_takes_raw_and_compressed_frames(flavor) -> None:
    from msg_utils import camera_image_to_rgb, numpy_to_image

    rgb = smooth_rgb()
    grey = rgb[..., 1].copy()
    raw = camera_image_to_rgb(numpy_to_image(rgb, 'rgb8', flavor=flavor))
    np.testing.assert_array_equal(raw, rgb)
    mono = camera_image_to_rgb(numpy_to_image(grey, 'mono8', flavor=flavor))
    np.testing.assert_array_equal(mono, np.repeat(grey[..., None], 3, axis=2))
    png = camera_image_to_rgb(numpy_to_compressed_image(grey, 'png', encoding='mono8', flavor=flavor))
    np.testing.assert_array_equal(png, np.repeat(grey[..., None], 3, axis=2))
    jpeg = camera_image_to_rgb(numpy_to_compressed_image(rgb, 'jpeg', encoding='rgb8', flavor=flavor))
    assert jpeg.shape == rgb.shape
    assert jpeg.dtype == np.uint8
    assert jpeg.flags.c_contiguous
    depth = numpy_to_compressed_depth(np.full((8, 8), 2000, np.uint16), flavor=flavor)
    with pytest.raises(MessageError, match=r'CompressedImage\.format'):
        camera_image_to_rgb(depth)
