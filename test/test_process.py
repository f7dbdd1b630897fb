"""``ibr process``: a short synthetic flight through the offline pipeline into an output bag.

One small orbit (320x180, 12 frames) with the frame_subsampler's scene depth hint of the demo
(80 m): 4 keyframes, 3 novel views. Checks the output bag with rosbags and the mcap reader, its
topics, types, counts and stamps, the depth against the exact ground truth, determinism, the
parameter files and the CLI's errors.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import msg_utils
from ibr_ros.bag import BagWriter, open_bag
from ibr_ros.cli.main import main
from ibr_ros.errors import UserError
from ibr_ros.jobs.process import OUT_TOPICS, ProcessOptions, load_params, process_bag
from ibr_ros.jobs.synth_bag import TOPICS, GroundTruthRenderer

PARAMS = 'frame_subsampler:\n  ros__parameters:\n    scene_depth_m: 80.0\n'
RUN = ['--max-keyframes', '4', '--views', '3', '--no-progress']


@pytest.fixture(scope='module')
def flight(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('process') / 'flight'
    args = ['bag', 'synth', '--seed', '5', '--trajectory', 'orbit', '--duration', '6', '--fps', '2']
    assert main([*args, '--size', '320x180', '--depth-every', '100', '--out', str(out)]) == 0
    return out


@pytest.fixture(scope='module')
def params(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp('params') / 'process.yaml'
    path.write_text(PARAMS)
    return path


@pytest.fixture(scope='module')
def processed(flight, params, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('out') / 'run'
    assert main(['process', str(flight), '--out', str(out), '--params', str(params), *RUN]) == 0
    return out


def _messages(bag: Path) -> dict[str, list[tuple[int, object, bytes]]]:
    by_topic: dict[str, list] = {}
    with open_bag(bag) as reader:
        for m in reader.messages():
            by_topic.setdefault(m.topic, []).append((m.timestamp_ns, m.msg, m.rawdata))
    return by_topic


def test_output_bag_topics_counts_and_stamps(processed):
    import json

    summary = json.loads((processed / 'summary.json').read_text())
    n, answered = summary['keyframes'], summary['views_answered']
    assert n == 4
    assert summary['refined'] == n
    assert summary['views_requested'] == 3
    assert answered == 3
    msgs = _messages(processed / 'bag')
    with open_bag(processed / 'bag') as reader:
        assert {t: i.msgtype for t, i in reader.topics.items()} == dict(OUT_TOPICS.values())
    counts = {t: len(v) for t, v in msgs.items()}
    keyframe_topics = [
        t for k, (t, _) in OUT_TOPICS.items() if k in ('image', 'camera_info', 'pose', 'depth', 'depth_info')
    ]
    assert counts == {**dict.fromkeys(keyframe_topics, n), '/novel_view/query': 3,
                      '/novel_view/image': answered, '/novel_view/camera_info': answered}  # fmt: skip
    assert counts == summary['output']['topics']
    stamps = {}
    for topic, rows in msgs.items():
        for log_time, msg, _ in rows:
            assert msg_utils.stamp_to_ns(msg.header.stamp) == log_time
        stamps[topic] = [r[0] for r in rows]
    kf_stamps = stamps['/keyframes/image']
    assert kf_stamps == sorted(kf_stamps)
    for topic in keyframe_topics:
        assert stamps[topic] == kf_stamps
    assert stamps['/novel_view/image'] == stamps['/novel_view/query'] == stamps['/novel_view/camera_info']
    assert all(kf_stamps[0] < s < kf_stamps[-1] for s in stamps['/novel_view/query'])
    assert {m.header.frame_id for _, m, _ in msgs['/novel_view/query']} == {'map'}
    # Keyframes are the input frames unchanged (rgb8), depth is REP-118 32FC1 with NaN for unknown.
    with open_bag(Path(summary['bag'])) as reader:
        jpeg = {m.header_stamp_ns: m.msg for m in reader.messages([TOPICS['image']])}
    _, first, _ = msgs['/keyframes/image'][0]
    assert first.encoding == 'rgb8'
    np.testing.assert_array_equal(
        msg_utils.image_to_rgb(first), msg_utils.compressed_image_to_numpy(jpeg[kf_stamps[0]])
    )
    for _, m, _ in msgs['/keyframes/depth']:
        assert m.encoding == '32FC1'
        depth = msg_utils.image_to_numpy(m)
        assert depth.shape == (180, 320)
        assert not (depth == 0).any()
    view = msgs['/novel_view/image'][0][1]
    assert (view.encoding, view.width, view.height) == ('rgb8', 320, 180)
    cam = msg_utils.camera_info_to_pinhole(msgs['/novel_view/camera_info'][0][1])
    assert (cam.width, cam.height) == (320, 180)
    md = (processed / 'summary.md').read_text()
    assert 'seconds per keyframe' in md
    assert summary['seconds_per_keyframe']['total'] > 0
    previews = sorted(p.name for p in (processed / 'previews').glob('*.png'))
    assert len(previews) == n + 3


def test_output_bag_readable_by_rosbags_and_mcap(processed):
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    from ibr_ros.bag import TYPESTORE

    with Reader(processed / 'bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages():
            TYPESTORE.deserialize_cdr(raw, conn.msgtype)
    assert counts['/keyframes/depth'] == 4
    seen: dict[str, int] = {}
    with (processed / 'bag' / 'bag_0.mcap').open('rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema.name == dict(OUT_TOPICS.values())[channel.topic]
            TYPESTORE.deserialize_cdr(message.data, schema.name)
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert seen == counts


def test_depth_close_to_ground_truth(processed, flight):
    import json

    gt_summary = json.loads((processed / 'summary.json').read_text())['ground_truth']
    assert gt_summary['depth_median_abs_rel'] < 0.1
    assert gt_summary['rephoto_auc_mean'] < 15.0
    # Recompute one keyframe's error from the bag alone.
    msgs = _messages(processed / 'bag')
    gt = GroundTruthRenderer(flight)
    _, depth_msg, _ = msgs['/keyframes/depth'][1]
    cam = msg_utils.camera_info_to_pinhole(msgs['/keyframes/depth/camera_info'][1][1])
    truth = gt.render(msg_utils.pose_stamped_to_matrix(msgs['/keyframes/pose'][1][1]), cam)
    d = msg_utils.image_to_numpy(depth_msg)
    ok = np.isfinite(truth.depth) & np.isfinite(d)
    assert ok.mean() > 0.5
    assert np.median(np.abs(d[ok] - truth.depth[ok]) / truth.depth[ok]) < 0.1


def test_deterministic(processed, flight, params, tmp_path):
    again = tmp_path / 'again'
    options = ProcessOptions(params=params, max_keyframes=4, views=3)
    process_bag(flight, again, options)
    a, b = _messages(processed / 'bag'), _messages(again / 'bag')
    for topic in ('/keyframes/depth', '/novel_view/image', '/novel_view/query'):
        assert [r[2] for r in a[topic]] == [r[2] for r in b[topic]], topic


def test_params_files(tmp_path, repo):
    import yaml

    defaults = load_params()
    config = yaml.safe_load((repo / 'config' / 'frame_subsampler.yaml').read_text())
    assert defaults['frame_subsampler'] == config['/**']['ros__parameters']
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    scene_depth_m: 50\n'
                    '/ns/view_renderer:\n  ros__parameters:\n    width: 64\n')  # fmt: skip
    p = load_params(path)
    assert p['frame_subsampler']['scene_depth_m'] == p['depth_refiner']['scene_depth_m'] == 50.0
    assert p['view_renderer']['width'] == 64
    path.write_text('depth_refiner:\n  ros__parameters:\n    max_neighbors: 2\n')
    with pytest.raises(UserError, match='max_neighbors'):
        load_params(path)
    path.write_text('depth_refiner:\n  ros__parameters:\n    max_neighbours: two\n')
    with pytest.raises(UserError, match=r'depth_refiner\.max_neighbours must be an integer'):
        load_params(path)


def _copy_topics(src: Path, dst: Path, topics: list[str], frames: int) -> None:
    with open_bag(src) as reader, BagWriter(dst) as writer:
        for m in reader.messages(topics, end_ns=reader.start_ns + frames * 500_000_000):
            writer.write_raw(m.topic, m.msgtype, m.rawdata, m.timestamp_ns)


def test_cli_errors(flight, processed, tmp_path, capsys):
    def run(*args: str) -> str:
        assert main(['process', *args, '--no-progress']) == 2
        err = capsys.readouterr().err
        assert err.startswith('ibr process: error:')
        assert err.count('\n') == 1
        return err

    no_pose = tmp_path / 'no_pose'
    _copy_topics(flight, no_pose, [TOPICS['image'], TOPICS['camera_info']], 2)
    assert 'no pose topic' in run(str(no_pose), '--out', str(tmp_path / 'o1'))
    no_info = tmp_path / 'no_info'
    _copy_topics(flight, no_info, [TOPICS['image'], TOPICS['pose']], 2)
    assert 'no camera_info topic' in run(str(no_info), '--out', str(tmp_path / 'o2'))
    assert '/nope' in run(str(flight), '--out', str(tmp_path / 'o3'), '--pose-topic', '/nope')
    assert 'expected' in run(str(flight), '--out', str(tmp_path / 'o4'), '--image-topic', TOPICS['pose'])
    empty = tmp_path / 'empty'
    with BagWriter(empty):
        pass
    assert 'no messages' in run(str(empty), '--out', str(tmp_path / 'o5'))
    assert 'exists already' in run(str(flight), '--out', str(processed))
    assert not (tmp_path / 'o1').exists()
