# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag from-images``: photos to a bag, on the real brighton_beach photos and on made-up ones."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.cli.main import main
from ibr_ros.errors import UserError
from ibr_ros.jobs.images_to_bag import TOPICS, images_to_bag

BRIGHTON = Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'brighton_beach'


@pytest.mark.skipif(not BRIGHTON.is_dir(), reason='needs ../shared/data/brighton_beach (not in a user clone)')
def test_brighton_beach_to_bag(tmp_path):
    out = tmp_path / 'bb'
    result = images_to_bag(BRIGHTON, out, max_width=800)
    assert (result.photos, result.with_gps, result.with_attitude) == (18, 18, 18)
    assert (out / 'LICENSE').read_text() == (BRIGHTON / 'LICENSE').read_text()
    with open_bag(out) as bag:
        assert {t: i.count for t, i in bag.topics.items()} == dict.fromkeys(TOPICS.values(), 18)
        images = list(bag.messages([TOPICS['image']]))
        infos = [m.msg for m in bag.messages([TOPICS['camera_info']])]
        fixes = [msg_utils.navsatfix_to_fix(m.msg) for m in bag.messages([TOPICS['navsat']])]
    stamps = [m.timestamp_ns for m in images]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == 18
    assert all(m.header_stamp_ns == m.timestamp_ns for m in images)
    rgb = msg_utils.compressed_image_to_numpy(images[0].msg)
    assert rgb.shape == (450, 800, 3)
    cam = msg_utils.camera_info_to_pinhole(infos[0])
    assert (cam.width, cam.height) == (800, 450)
    assert cam.fx == pytest.approx(936 / 2, rel=0.02)  # 3.61 mm / 6.17 mm * 800 px
    assert fixes[0].latitude_deg == pytest.approx(46.84260708, abs=1e-7)
    # Readable by the mcap reader too.
    (mcap_file,) = out.glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        decoded = list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    assert len(decoded) == 72


def _photo(path: Path, size=(64, 48), value=100) -> Path:
    cv2.imwrite(str(path), np.full((size[1], size[0], 3), value, np.uint8))
    return path


def test_photos_without_exif_are_spaced_one_second(tmp_path, caplog):
    src = tmp_path / 'src'
    src.mkdir()
    for i, name in enumerate(['b.jpg', 'a.png', 'c.JPG']):
        _photo(src / name, value=40 * i)
    with caplog.at_level(logging.WARNING):
        result = images_to_bag(src, tmp_path / 'out', fallback_hfov_deg=90.0)
    assert 'without EXIF capture time' in caplog.text
    assert 'no focal length' in caplog.text
    assert result.license_copied is None
    with open_bag(tmp_path / 'out') as bag:
        assert set(bag.topics) == {TOPICS['image'], TOPICS['camera_info']}
        msgs = list(bag.messages([TOPICS['image']]))
        info = next(iter(bag.messages([TOPICS['camera_info']]))).msg
    assert [m.timestamp_ns for m in msgs] == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    assert msg_utils.camera_info_to_pinhole(info).hfov_deg == pytest.approx(90.0)
    # Name order: a.png (value 40), b.jpg (0), c.JPG (80).
    means = [float(msg_utils.compressed_image_to_numpy(m.msg).mean()) for m in msgs]
    assert means == pytest.approx([40, 0, 80], abs=2)


def test_mixed_sizes_and_empty_folder_are_user_errors(tmp_path, capsys):
    src = tmp_path / 'mixed'
    src.mkdir()
    _photo(src / 'a.jpg', (64, 48))
    _photo(src / 'b.jpg', (32, 48))
    with pytest.raises(UserError, match='differ in size'):
        images_to_bag(src, tmp_path / 'out')
    assert not (tmp_path / 'out').exists()
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert main(['bag', 'from-images', str(empty), '--out', str(tmp_path / 'o2')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert 'no photos' in err[0]
    assert str(empty) in err[0]
