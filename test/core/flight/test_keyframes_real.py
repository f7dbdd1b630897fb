# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Keyframe blur on the shipped real captures: no sharp photo is rejected, blurred copies are."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import msg_utils
from ibr_ros.bag import detect_topics, open_bag
from ibr_ros.core.flight.keyframes import IntervalSelector, KeyframeConfig, blur_px, detail_score


def _photos(bag: Path) -> list[tuple[int, np.ndarray]]:
    """(header stamp ns, rgb8) of every photo of ``bag``."""
    with open_bag(bag) as reader:
        topic = detect_topics(reader).image
        assert topic is not None
        return [
            (msg_utils.stamp_to_ns(m.msg.header.stamp), msg_utils.camera_image_to_rgb(m.msg))
            for m in reader.messages([topic])
        ]


@pytest.mark.parametrize(('name', 'count'), [('brighton_beach', 18), ('sheffield_cross', 39)])
def test_real_stills_none_rejected_blurred_copies_are(repo: Path, name: str, count: int) -> None:
    """Survey stills 6-7 s apart over trees, lawn, water and houses: with the frame_subsampler's
    defaults (1 s windows) every photo is a keyframe, none dropped as blurred; the same photos
    after a Gaussian blur of sigma 1.5 px or a 5 px motion blur are over max_blur_px."""
    photos = _photos(repo / 'bags' / name)
    assert len(photos) == count
    config = KeyframeConfig()
    sel: IntervalSelector[int] = IntervalSelector(1.0, config)
    picks = []
    for i, (stamp, rgb) in enumerate(photos):
        picks += sel.push(stamp, blur_px(rgb), i, detail=detail_score(rgb))
    picks += sel.flush()
    assert [p.item for p in picks] == list(range(count))
    assert sel.rejected == {'blurred': 0, 'late': 0}
    motion = np.full((1, 5), 0.2, np.float32)
    for _, rgb in photos[::4]:
        assert blur_px(cv2.GaussianBlur(rgb, (0, 0), 1.5)) > config.max_blur_px
        assert blur_px(cv2.filter2D(rgb, -1, motion)) > config.max_blur_px
