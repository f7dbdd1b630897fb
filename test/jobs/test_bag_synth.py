# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag synth``: a deterministic synthetic flight with ground truth, written as a bag."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import msg_utils
from ibr_ros.bag import open_bag
from ibr_ros.cli.main import main
from ibr_ros.core.synth import SceneConfig, flight_camera, render_view
from ibr_ros.jobs.synth_bag import START_NS, TOPICS, GroundTruthRenderer, quantize_depth

ARGS = ['--duration', '0.5', '--fps', '4', '--size', '96x64', '--trajectory', 'lawnmower']


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('synth') / 'flight'
    assert main(['bag', 'synth', '--seed', '3', *ARGS, '--out', str(out)]) == 0
    return out


def test_same_seed_is_bit_identical(short_bag, tmp_path):
    # Same folder name: the name is recorded in metadata.yaml and in the MCAP's metadata record.
    again = tmp_path / 'a' / short_bag.name
    assert main(['bag', 'synth', '--seed', '3', *ARGS, '--out', str(again)]) == 0
    assert _digest(again) == _digest(short_bag)
    other = tmp_path / 'b' / short_bag.name
    assert main(['bag', 'synth', '--seed', '4', *ARGS, '--out', str(other)]) == 0
    assert _digest(other)[f'{other.name}_0.mcap'] != _digest(short_bag)[f'{short_bag.name}_0.mcap']


def test_topics_stamps_and_ground_truth(short_bag):
    with open_bag(short_bag) as bag:
        assert {t: i.count for t, i in bag.topics.items()} == dict.fromkeys(TOPICS.values(), 2)
        by_topic: dict[str, list] = {}
        for m in bag.messages():
            assert m.header_stamp_ns == m.timestamp_ns
            by_topic.setdefault(m.topic, []).append(m.msg)
    camera = msg_utils.camera_info_to_pinhole(by_topic[TOPICS['camera_info']][1])
    assert camera == flight_camera((96, 64), 70.0)
    t_wc = msg_utils.pose_stamped_to_matrix(by_topic[TOPICS['pose']][1])
    assert by_topic[TOPICS['pose']][1].header.frame_id == 'map'
    # The GT in the bag is exactly what the renderer gives for that pose.
    from ibr_ros.core.synth import build_scene

    frame = render_view(build_scene(SceneConfig(seed=3)), camera, t_wc)
    depth = msg_utils.image_to_numpy(by_topic[TOPICS['depth']][1])
    np.testing.assert_allclose(depth, frame.depth, rtol=1e-6)
    sky = msg_utils.image_to_numpy(by_topic[TOPICS['sky_mask']][1])
    np.testing.assert_array_equal(sky == 255, frame.sky)
    np.testing.assert_array_equal(msg_utils.image_to_numpy(by_topic[TOPICS['labels']][1]), frame.label)
    jpeg = msg_utils.numpy_to_compressed_image(frame.rgb, 'jpeg', quality=90, flavor='rosbags')
    assert bytes(by_topic[TOPICS['image']][1].data) == bytes(jpeg.data)


def test_depth_every_and_quantisation(tmp_path):
    out = tmp_path / 'q'
    args = [
        '--duration',
        '1',
        '--fps',
        '4',
        '--size',
        '64x48',
        '--depth-every',
        '2',
        '--depth-mantissa-bits',
        '10',
    ]
    assert main(['bag', 'synth', *args, '--no-labels', '--out', str(out)]) == 0
    with open_bag(out) as bag:
        counts = {t: i.count for t, i in bag.topics.items()}
    assert counts[TOPICS['image']] == 4
    assert counts[TOPICS['depth']] == 2
    assert TOPICS['labels'] not in counts


@settings(max_examples=60, deadline=None)
@given(
    arrays(
        np.float32, (7, 5), elements=st.floats(0.0009765625, 1e6, width=32) | st.just(np.inf) | st.just(0.0)
    ),
    st.integers(1, 23),
)
def test_quantize_depth_bound(depth, bits):
    q = quantize_depth(depth, bits)
    finite = np.isfinite(depth) & (depth > 0)
    rel = np.abs(q[finite].astype(np.float64) - depth[finite]) / depth[finite]
    assert (rel <= 2.0 ** -(bits + 1) + 1e-12).all()
    np.testing.assert_array_equal(q[~finite], depth[~finite])
    np.testing.assert_array_equal(quantize_depth(q, bits), q)  # idempotent


def test_pitch_range(tmp_path):
    out = tmp_path / 'low'
    args = ['--duration', '1', '--fps', '2', '--size', '64x36', '--pitch=-6,-12', '--no-labels']
    assert main(['bag', 'synth', *args, '--out', str(out)]) == 0
    with open_bag(out) as bag:
        poses = [msg_utils.pose_stamped_to_matrix(m.msg) for m in bag.messages([TOPICS['pose']])]
    # The optical axis (third column) rises by sin(pitch): the orbit looks down at 12 deg, not lower.
    pitch = np.degrees(np.arcsin([t[2, 2] for t in poses]))
    assert len(pitch) == 2
    assert pitch.min() >= -12 - 1e-9
    assert pitch.max() <= -6 + 1e-9
    assert GroundTruthRenderer(out).flight['pitch_range_deg'] == [-12.0, -6.0]
    for bad in ('--pitch=-5', '--pitch=-10,5', '--pitch=a,b', '--pitch=-95,-10'):
        with pytest.raises(SystemExit):
            main(['bag', 'synth', bad, '--out', str(tmp_path / 'bad')])


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(['bag', 'synth', '--duration', '0', '--out', str(tmp_path / 'x')]) == 2
    assert 'must be positive' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['bag', 'synth', '--size', '10x', '--out', str(tmp_path / 'y')])


def test_shipped_bag_matches_its_sidecar(repo):
    """The default bag's ground truth is what its synth.json re-renders (README command is honest)."""
    bag_dir = repo / 'bags' / 'synth_orbit_s0'
    gt = GroundTruthRenderer(bag_dir)
    assert gt.flight['depth_every'] == 3
    with open_bag(bag_dir) as bag:
        depth_msg = next(iter(bag.messages([TOPICS['depth']], start_ns=START_NS + 300_000_000)))
        stamp = depth_msg.timestamp_ns
        pose_msg = next(m for m in bag.messages([TOPICS['pose']]) if m.timestamp_ns == stamp)
        info_msg = next(m for m in bag.messages([TOPICS['camera_info']]) if m.timestamp_ns == stamp)
    camera = msg_utils.camera_info_to_pinhole(info_msg.msg)
    frame = gt.render(msg_utils.pose_stamped_to_matrix(pose_msg.msg), camera)
    stored = msg_utils.image_to_numpy(depth_msg.msg)
    np.testing.assert_array_equal(stored, quantize_depth(frame.depth, 10))
