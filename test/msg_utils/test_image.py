# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""msg_utils.image: sensor_msgs/Image <-> numpy for both flavours, depth conventions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image

from msg_utils import (
    ENCODINGS,
    MessageError,
    confidence_to_image,
    depth_image_to_m,
    depth_m_to_image,
    depth_m_to_mm,
    depth_mm_to_m,
    image_to_confidence,
    image_to_numpy,
    image_to_rgb,
    is_rosbags_message,
    make_header,
    message_typename,
    new_message,
    numpy_to_image,
    stamp_to_ns,
    typestore,
)

FLAVORS = ('rclpy', 'rosbags')


def random_image(encoding: str, h: int, w: int, seed: int) -> np.ndarray:
    dtype, channels = ENCODINGS[encoding]
    rng = np.random.default_rng(seed)
    shape = (h, w) if channels == 1 else (h, w, channels)
    if dtype.kind == 'f':
        a = (rng.standard_normal(shape) * 100).astype(dtype)
        a.reshape(-1)[:: max(1, a.size // 3)] = np.nan
        return a
    return rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype, endpoint=True)


def raw_image(a: np.ndarray, encoding: str, *, pad: int, big_endian: bool, flavor: str):
    """An Image built by hand: rows padded by ``pad`` bytes, data in the given byte order."""
    stored = a.astype(a.dtype.newbyteorder('>' if big_endian else '<'))
    h, w = a.shape[:2]
    row = stored.reshape(h, -1).view(np.uint8).reshape(h, -1)
    rows = np.concatenate([row, np.full((h, pad), 0xAB, np.uint8)], axis=1)
    data = rows.tobytes()
    if flavor == 'rosbags':
        data = np.frombuffer(data, np.uint8).copy()
    return new_message(
        'sensor_msgs/msg/Image',
        flavor,
        header=make_header(7, 'cam', flavor),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(big_endian),
        step=row.shape[1] + pad,
        data=data,
    )


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@settings(max_examples=60, deadline=None)
@given(
    encoding=st.sampled_from(sorted(ENCODINGS)),
    h=st.integers(1, 9),
    w=st.integers(1, 9),
    seed=st.integers(0, 2**32 - 1),
    flavor=st.sampled_from(FLAVORS),
)
def test_numpy_image_round_trip(encoding, h, w, seed, flavor):
    a = random_image(encoding, h, w, seed)
    msg = numpy_to_image(a, encoding, make_header(123, 'cam', flavor), flavor=flavor)
    assert is_rosbags_message(msg) == (flavor == 'rosbags')
    assert (msg.height, msg.width, msg.encoding) == (h, w, encoding)
    assert msg.step == w * a.itemsize * (a.shape[2] if a.ndim == 3 else 1)
    assert stamp_to_ns(msg.header.stamp) == 123
    assert same(image_to_numpy(msg), a)


@settings(max_examples=60, deadline=None)
@given(
    encoding=st.sampled_from(sorted(ENCODINGS)),
    h=st.integers(1, 7),
    w=st.integers(1, 7),
    pad=st.integers(0, 9),
    big_endian=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
    flavor=st.sampled_from(FLAVORS),
)
def test_padded_step_and_byte_order(encoding, h, w, pad, big_endian, seed, flavor):
    a = random_image(encoding, h, w, seed)
    out = image_to_numpy(raw_image(a, encoding, pad=pad, big_endian=big_endian, flavor=flavor))
    assert same(out, a)
    assert not out.flags.writeable


@pytest.mark.parametrize('flavor', FLAVORS)
def test_zero_size_image(flavor):
    msg = numpy_to_image(np.zeros((0, 5, 3), np.uint8), 'rgb8', flavor=flavor)
    assert image_to_numpy(msg).shape == (0, 5, 3)


@pytest.mark.parametrize('flavor', FLAVORS)
def test_message_owns_a_copy_and_reading_is_zero_copy(flavor):
    a = random_image('rgb8', 4, 5, 0)
    msg = numpy_to_image(a, 'rgb8', flavor=flavor)
    a[:] = 0
    out = image_to_numpy(msg)
    assert out.any()
    assert np.shares_memory(out, np.frombuffer(msg.data, np.uint8))
    with pytest.raises(ValueError, match='read-only'):
        out[0, 0, 0] = 1


def test_accepts_hxwx1_non_contiguous_and_foreign_byte_order():
    a = random_image('16UC1', 6, 8, 1)
    assert same(image_to_numpy(numpy_to_image(a[:, :, None], '16UC1')), a)
    assert same(image_to_numpy(numpy_to_image(a[:, ::2], '16UC1')), a[:, ::2])
    assert same(image_to_numpy(numpy_to_image(a.astype('>u2'), '16UC1')), a)


def test_rclpy_data_is_a_plain_uint8_array_and_survives_serialization():
    a = random_image('bgra8', 3, 4, 2)
    msg = numpy_to_image(a, 'bgra8')
    assert msg.data.typecode == 'B'
    back = deserialize_message(serialize_message(msg), Image)
    assert back == msg
    assert same(image_to_numpy(back), a)


def assert_same_cdr(rclpy_msg, rosbags_msg) -> None:
    """Both flavours serialize to the same CDR bytes and each deserializes the other's.

    rmw leaves CDR alignment padding uninitialised, so raw bytes may differ only where rosbags
    wrote padding (zeros); after a rosbags round trip the rclpy bytes must be identical.
    """
    typename = message_typename(rclpy_msg)
    assert message_typename(rosbags_msg) == typename
    ts = typestore()
    raw_rclpy = bytes(serialize_message(rclpy_msg))
    raw_bag = bytes(ts.serialize_cdr(rosbags_msg, typename))
    assert len(raw_rclpy) == len(raw_bag)
    assert bytes(ts.serialize_cdr(ts.deserialize_cdr(raw_rclpy, typename), typename)) == raw_bag
    assert all(raw_bag[i] == 0 for i in range(len(raw_bag)) if raw_bag[i] != raw_rclpy[i])
    assert deserialize_message(raw_bag, type(rclpy_msg)) == rclpy_msg


@pytest.mark.parametrize('encoding', ['rgb8', 'mono16', '32FC1'])
def test_flavours_serialize_to_identical_cdr(encoding):
    a = random_image(encoding, 5, 3, 3)
    header = {'stamp_ns': 1_700_000_000_123_456_789, 'frame_id': 'camera_optical'}
    msgs = {f: numpy_to_image(a, encoding, make_header(**header, flavor=f), flavor=f) for f in FLAVORS}
    assert_same_cdr(msgs['rclpy'], msgs['rosbags'])
    from_bag = typestore().deserialize_cdr(serialize_message(msgs['rclpy']), 'sensor_msgs/msg/Image')
    assert same(image_to_numpy(from_bag), a)


def test_header_of_the_other_flavour_is_converted():
    msg = numpy_to_image(np.zeros((2, 2), np.uint8), 'mono8', make_header(5, 'x', 'rclpy'), flavor='rosbags')
    assert is_rosbags_message(msg.header)
    assert (stamp_to_ns(msg.header.stamp), msg.header.frame_id) == (5, 'x')


# -- errors ------------------------------------------------------------------------------------


def test_step_smaller_than_row_names_field_and_value():
    msg = numpy_to_image(np.zeros((2, 40, 3), np.uint8), 'rgb8')
    msg.step = 100
    with pytest.raises(MessageError, match=r'Image\.step 100 is smaller than width\*3 = 120'):
        image_to_numpy(msg)


def test_data_length_mismatch():
    msg = numpy_to_image(np.zeros((2, 4), np.uint16), '16UC1')
    msg.data = msg.data[:-1]
    with pytest.raises(MessageError, match=r'Image\.data has 15 bytes, expected step\*height = 8\*2 = 16'):
        image_to_numpy(msg)


def test_unknown_encoding():
    msg = numpy_to_image(np.zeros((2, 4), np.uint8), 'mono8')
    msg.encoding = 'yuv422'
    with pytest.raises(MessageError, match=r"Image\.encoding 'yuv422' is not supported"):
        image_to_numpy(msg)
    with pytest.raises(MessageError, match="encoding 'yuv422'"):
        numpy_to_image(np.zeros((2, 4), np.uint8), 'yuv422')


@pytest.mark.parametrize(
    ('array', 'encoding', 'match'),
    [
        (np.zeros((2, 3), np.float64), '32FC1', 'needs dtype float32, got float64'),
        (np.zeros((2, 3), np.uint8), 'rgb8', r"'rgb8' needs HxWx3, got \(2, 3\)"),
        (np.zeros((2, 3, 4), np.uint8), 'rgb8', 'HxWx3'),
        (np.zeros((2, 3, 3), np.uint8), 'mono8', 'HxW'),
    ],
)
def test_array_that_does_not_fit_the_encoding(array, encoding, match):
    with pytest.raises(MessageError, match=match):
        numpy_to_image(array, encoding)


# -- RGB -------------------------------------------------------------------------------------


@pytest.mark.parametrize('flavor', FLAVORS)
@pytest.mark.parametrize('encoding', ['rgb8', 'bgr8', 'rgba8', 'bgra8', 'mono8', '8UC1'])
def test_image_to_rgb(encoding, flavor):
    a = random_image(encoding, 3, 5, 4)
    rgb = image_to_rgb(raw_image(a, encoding, pad=3, big_endian=False, flavor=flavor))
    expected = {
        'rgb8': a,
        'bgr8': a[..., ::-1],
        'rgba8': a[..., :3],
        'bgra8': a[..., 2::-1],
    }.get(encoding, np.repeat(a[..., None], 3, axis=2))
    assert rgb.dtype == np.uint8
    assert np.array_equal(rgb, expected)


@pytest.mark.parametrize('encoding', ['8UC3', 'mono16', '32FC1'])
def test_image_to_rgb_refuses_ambiguous_or_deep_encodings(encoding):
    msg = numpy_to_image(random_image(encoding, 2, 2, 0), encoding)
    with pytest.raises(MessageError, match=f"Image.encoding '{encoding}' cannot be converted to RGB"):
        image_to_rgb(msg)


# -- depth -----------------------------------------------------------------------------------


def test_every_millimetre_survives_m_and_back():
    mm = np.arange(65536, dtype=np.uint16)
    m = depth_mm_to_m(mm)
    assert m.dtype == np.float32
    assert m[0] == 0.0
    assert m[1500] == np.float32(1.5)
    assert np.array_equal(depth_m_to_mm(m), mm)


def test_metres_to_mm_rounding_and_unknowns():
    m = np.array(
        [0.0012, 0.0015, 1.2344, 1.2346, 65.535, 65.5356, 70.0, 0.0, -1.0, np.nan, np.inf, -np.inf, 4e-4]
    )
    mm = depth_m_to_mm(m.astype(np.float32))
    assert mm.dtype == np.uint16
    assert mm.tolist() == [1, 2, 1234, 1235, 65535, 0, 0, 0, 0, 0, 0, 0, 0]


def test_depth_mm_to_m_rejects_signed_or_float_input():
    with pytest.raises(MessageError, match='unsigned integer'):
        depth_mm_to_m(np.array([1.0]))


@pytest.mark.parametrize('flavor', FLAVORS)
def test_depth_image_to_m(flavor):
    mm = np.array([[0, 1, 1000], [2500, 65535, 7]], np.uint16)
    out = depth_image_to_m(numpy_to_image(mm, '16UC1', flavor=flavor))
    assert out.dtype == np.float32
    assert np.array_equal(out, mm.astype(np.float32) / np.float32(1000))

    m = np.array([[np.nan, 1.5, np.inf], [-np.inf, -2.0, 0.0]], np.float32)
    out = depth_image_to_m(numpy_to_image(m, '32FC1', flavor=flavor))
    assert out.dtype == np.float32
    assert out.tolist() == [[0.0, 1.5, np.inf], [0.0, 0.0, 0.0]]
    assert out.flags.writeable


@pytest.mark.parametrize('flavor', FLAVORS)
def test_depth_m_to_image_marks_unknown_as_nan(flavor):
    d = np.array([[0.0, 1.5, np.inf], [-2.0, np.nan, 40.0]], np.float32)
    msg = depth_m_to_image(d, make_header(7, 'cam', flavor), flavor=flavor)
    assert msg.encoding == '32FC1'
    assert msg.header.frame_id == 'cam'
    out = image_to_numpy(msg)
    assert np.isnan(out[[0, 1, 1], [0, 0, 1]]).all()
    assert out[0, 1] == 1.5
    assert out[0, 2] == np.inf
    assert out[1, 2] == 40.0
    np.testing.assert_array_equal(depth_image_to_m(msg), np.where(d > 0, d, 0))


def test_depth_image_to_m_rejects_colour():
    with pytest.raises(MessageError, match=r"Image\.encoding 'rgb8' is not a depth encoding"):
        depth_image_to_m(numpy_to_image(np.zeros((1, 1, 3), np.uint8), 'rgb8'))


@pytest.mark.parametrize('flavor', FLAVORS)
def test_confidence_round_trip_and_checks(flavor):
    c = np.array([[0.0, 0.25], [0.5, 1.0]], np.float32)
    msg = confidence_to_image(c, make_header(7, 'cam', flavor), flavor=flavor)
    assert msg.encoding == '32FC1'
    assert np.array_equal(image_to_confidence(msg), c)
    raw = numpy_to_image(np.array([[np.nan, 1.5], [-0.5, 0.5]], np.float32), '32FC1', flavor=flavor)
    assert image_to_confidence(raw).tolist() == [[0.0, 1.0], [0.0, 0.5]]  # NaN -> 0, clipped
    with pytest.raises(MessageError, match=r'confidence must be finite and in \[0, 1\], got 1.5'):
        confidence_to_image(np.array([[1.5]], np.float32), flavor=flavor)
    with pytest.raises(MessageError, match="encoding 'mono8': a depth confidence is 32FC1"):
        image_to_confidence(numpy_to_image(np.zeros((2, 2), np.uint8), 'mono8', flavor=flavor))
