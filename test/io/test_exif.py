# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Photo metadata from EXIF / DJI XMP."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from PIL.TiffImagePlugin import IFDRational as Fraction

from ibr_ros.errors import UserError
from ibr_ros.io.exif import initial_camera, read_photo_metadata

BRIGHTON = Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'brighton_beach' / 'images'


def _jpeg(path: Path, exif: Image.Exif | None = None, xmp: bytes | None = None) -> Path:
    im = Image.fromarray(np.full((60, 80, 3), 128, np.uint8))
    kwargs = {}
    if exif is not None:
        kwargs['exif'] = exif
    if xmp is not None:
        kwargs['xmp'] = xmp
    im.save(path, 'JPEG', **kwargs)
    return path


@pytest.mark.skipif(not BRIGHTON.is_dir(), reason='needs ../shared/data/brighton_beach (not in a user clone)')
def test_real_dji_photo():
    meta = read_photo_metadata(BRIGHTON / 'DJI_0018.JPG')
    assert (meta.width, meta.height) == (1600, 900)
    assert meta.make == 'DJI'
    assert meta.model == 'FC300S'
    assert meta.capture_time_ns == 1466699519 * 10**9  # 2016:06:23 16:31:59, read as UTC
    assert meta.latitude_deg == pytest.approx(46.84260708, abs=1e-7)
    assert meta.longitude_deg == pytest.approx(-91.99455989, abs=1e-7)
    assert meta.altitude_m == pytest.approx(198.309)
    assert meta.relative_altitude_m == pytest.approx(39.8)
    assert (meta.gimbal.yaw_deg, meta.gimbal.pitch_deg) == (45.0, -89.9)
    # Looking straight down, heading north-east: image right points south-east.
    r = meta.gimbal.rotation_enu()
    assert r[:, 2] == pytest.approx([0, 0, -1], abs=3e-3)
    assert r[:, 0] == pytest.approx([math.sqrt(0.5), -math.sqrt(0.5), 0], abs=3e-3)
    cam, how = initial_camera(meta)
    # True focal: 3.61 mm on a 6.17 mm wide sensor -> 936 px at 1600 px; the 4:3 guess is within 2%.
    assert cam.fx == pytest.approx(936, rel=0.02)
    assert '35mm' in how.replace(' ', '')


def test_focal_plane_resolution_preferred(tmp_path):
    exif = Image.Exif()
    ifd = exif.get_ifd(0x8769)
    ifd[0x920A] = Fraction(4)  # FocalLength 4 mm
    ifd[0xA20E] = Fraction(500)  # 500 px per unit
    ifd[0xA210] = 4  # unit = mm
    ifd[0xA002] = 160  # original width: the file is half of it
    ifd[0x9003] = '2020:01:02 03:04:05'
    ifd[0x9011] = '+02:00'
    meta = read_photo_metadata(_jpeg(tmp_path / 'a.jpg', exif))
    cam, how = initial_camera(meta)
    assert cam.fx == pytest.approx(4 * 500 * 80 / 160)
    assert 'FocalPlaneXResolution' in how
    assert meta.capture_time_ns == (1577934245 - 7200) * 10**9


def test_gps_south_west_and_xmp_elements(tmp_path):
    exif = Image.Exif()
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2] = 'S', (Fraction(10), Fraction(30), Fraction(0))
    gps[3], gps[4] = 'W', (Fraction(20), Fraction(0), Fraction(36))
    gps[5], gps[6] = b'\x01', Fraction(5)
    xmp = (
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF><rdf:Description>'
        b'<drone-dji:GimbalYawDegree>-90.0</drone-dji:GimbalYawDegree>'
        b'<drone-dji:GimbalPitchDegree>-30.0</drone-dji:GimbalPitchDegree>'
        b'<drone-dji:GimbalRollDegree>0</drone-dji:GimbalRollDegree>'
        b'</rdf:Description></rdf:RDF></x:xmpmeta>'
    )
    meta = read_photo_metadata(_jpeg(tmp_path / 'b.jpg', exif, xmp))
    assert meta.latitude_deg == pytest.approx(-10.5)
    assert meta.longitude_deg == pytest.approx(-20.01)
    assert meta.altitude_m == pytest.approx(-5.0)
    # Heading west, 30 deg down: the optical axis points west and down.
    z = meta.gimbal.rotation_enu()[:, 2]
    assert z == pytest.approx([-math.cos(math.radians(30)), 0, -math.sin(math.radians(30))], abs=1e-9)


def test_no_exif_falls_back_with_warning(tmp_path, caplog):
    meta = read_photo_metadata(_jpeg(tmp_path / 'c.jpg'))
    assert meta.capture_time_ns is None
    assert not meta.has_gps
    assert meta.gimbal is None
    with caplog.at_level(logging.WARNING):
        cam, how = initial_camera(meta, fallback_hfov_deg=60.0)
    assert cam.hfov_deg == pytest.approx(60.0)
    assert 'assumed' in how
    assert 'no focal length' in caplog.text


def test_not_an_image(tmp_path):
    bad = tmp_path / 'bad.jpg'
    bad.write_bytes(b'not a jpeg')
    with pytest.raises(UserError, match=r'bad\.jpg: not a readable image'):
        read_photo_metadata(bad)
