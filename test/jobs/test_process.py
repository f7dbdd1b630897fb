# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr process``: a short synthetic flight through the offline pipeline into an output bag.

One small orbit (320x180, 12 frames) with the frame_subsampler's scene depth hint of the demo
(80 m): 4 keyframes, 3 novel views. Checks the output bag with rosbags and the mcap reader, its
topics, types, counts and stamps, the depth against the exact ground truth, determinism, the
parameter files and the CLI's errors.

SfM mode: the same flight without its pose topic (6 keyframes, one per 1 s window, registered by
SfM in the ``sfm`` frame; depth checked against the ground truth after a similarity fit), the
flight with ``--sfm`` (ground-truth evaluation in the summary), and the real brighton_beach photos
with GPS (ENU frame; 7 keyframes spread over the flight by ``poseless_interval_s`` 20, ~15 s).

``--target-keyframes``: 10 of the flight's 12 frames by ``select_keyframes`` (refined and rendered), and
the two passes over a bag with undecodable images.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import msg_utils
from ibr_ros.bag import TYPESTORE, BagWriter, OfferedQos, open_bag
from ibr_ros.cli.main import main
from ibr_ros.core.registration.sfm import umeyama
from ibr_ros.errors import UserError
from ibr_ros.jobs.process import OUT_TOPICS, ProcessOptions, load_params, process_bag
from ibr_ros.jobs.synth_bag import TOPICS, GroundTruthRenderer

pytestmark = pytest.mark.e2e

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
        # no NavSatFix in the input: no /gps/fix in the output (not even declared)
        out_topics = dict(v for k, v in OUT_TOPICS.items() if k != 'navsat')
        assert {t: i.msgtype for t, i in reader.topics.items()} == out_topics
        # recorded as the graph offers them, so bag_player replays keyframes to late-joining renderers
        durability = {t: {q.durability for q in i.offered_qos} for t, i in reader.topics.items()}
    expected = {
        t: {'transient_local' if t.startswith('/keyframes/') or t == '/tf_static' else 'volatile'}
        for t in durability
    }
    assert durability == expected
    counts = {t: len(v) for t, v in msgs.items()}
    keyframe_topics = [
        t
        for k, (t, _) in OUT_TOPICS.items()
        if k in ('image', 'camera_info', 'pose', 'depth', 'depth_info', 'confidence')
    ]
    assert counts == {**dict.fromkeys(keyframe_topics, n), '/novel_view/query': 3, '/novel_view/status': 3,
                      '/novel_view/image': answered, '/novel_view/camera_info': answered,
                      '/novel_view/image/compressed': answered,
                      # the scene_viz's: per keyframe, and the novel view's frustum and TF per answer
                      '/keyframes/points': n, '/keyframes/poses': n, '/tf_static': n,
                      '/keyframes/frustums': n + answered, '/tf': n + answered}  # fmt: skip
    assert counts == summary['output']['topics']
    stamps = {}
    for topic, rows in msgs.items():
        for log_time, msg, _ in rows:
            for h in _headers(msg):
                assert msg_utils.stamp_to_ns(h.stamp) == log_time or topic == '/tf_static', topic
        stamps[topic] = [r[0] for r in rows]
    kf_stamps = stamps['/keyframes/image']
    assert kf_stamps == sorted(kf_stamps)
    for topic in keyframe_topics:
        assert stamps[topic] == kf_stamps
    assert stamps['/novel_view/image'] == stamps['/novel_view/query'] == stamps['/novel_view/camera_info']
    assert stamps['/novel_view/status'] == stamps['/novel_view/query']
    # Every query's status, as the view_renderer publishes it; the summary records the same.
    replies = [msg_utils.diagnostics_to_reply(m) for _, m, _ in msgs['/novel_view/status']]
    rows = summary['novel_views']
    assert [s for s, _ in replies] == [r['stamp'] for r in rows] == stamps['/novel_view/query']
    for (_, st), row in zip(replies, rows):
        assert (st.result, st.reason) == (row['result'], row['reason']) == ('answered', '')
        assert st.valid_fraction == row['valid_fraction'] >= st.min_valid_fraction
        assert len(st.views) == len(row['views']) > 0
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
    fractions = [r['valid_fraction'] for r in rows]
    assert f'**answered**: 3/3 novel views (valid fraction {min(fractions):.2f} .. {max(fractions):.2f}' in md
    assert summary['seconds_per_keyframe']['total'] > 0
    previews = sorted(p.name for p in (processed / 'previews').glob('*.png'))
    assert len(previews) == n + 3


def _headers(msg: object) -> list:
    """The headers of a message: its own, or its transforms' / markers' (TFMessage, MarkerArray)."""
    if hasattr(msg, 'header'):
        return [msg.header]
    return [m.header for m in getattr(msg, 'transforms', None) or getattr(msg, 'markers', [])]


def _tf_tree(msgs: list) -> dict[str, tuple[str, np.ndarray]]:
    """child -> (parent, T child-to-parent) of TFMessages, the later winning (a TF buffer at one time)."""
    tree = {}
    for m in msgs:
        for tf in m.transforms:
            tree[tf.child_frame_id] = (tf.header.frame_id, msg_utils.transform_stamped_to_matrix(tf))
    return tree


def _lookup(tree: dict, target: str, source: str) -> np.ndarray:
    """The transform from ``source`` to ``target`` coordinates, walking ``source`` up the tree."""
    t, frame = np.eye(4), source
    while frame != target:
        assert frame in tree, f'no TF chain from {source} to {target} (stuck at {frame})'
        frame, step = tree[frame]
        t = step @ t
    return t


def test_output_bag_shows_the_model_in_viewers(processed):
    """TF resolvable and equal to the poses, points on the depth, frustums and poses of every keyframe."""
    from ibr_ros.core.viz import keyframe_points
    from ibr_ros.node_config import SCENE_VIZ

    cfg = SCENE_VIZ.config({})
    msgs = _messages(processed / 'bag')
    kf = {s: {'pose': msg_utils.pose_stamped_to_matrix(m)} for s, m, _ in msgs['/keyframes/pose']}
    for topic, key, conv in (
        ('/keyframes/image', 'rgb', msg_utils.image_to_rgb),
        ('/keyframes/depth', 'depth', msg_utils.depth_image_to_m),
        ('/keyframes/depth/confidence', 'conf', msg_utils.image_to_confidence),
        ('/keyframes/camera_info', 'cam', msg_utils.camera_info_to_pinhole),
    ):
        for s, m, _ in msgs[topic]:
            kf[s][key] = conv(m)
    # TF: the keyframes on /tf_static (latched: the last message holds them all), the camera on /tf.
    static = _tf_tree([msgs['/tf_static'][-1][1]])
    for s, k in kf.items():
        np.testing.assert_allclose(
            _lookup(static, 'map', f'keyframe_{s}_optical_frame'), k['pose'], atol=1e-9
        )
    dynamic = {s: m for s, m, _ in msgs['/tf']}
    for s, k in kf.items():
        tree = _tf_tree([dynamic[s]])
        assert tree['camera_optical_frame'][0] == 'camera_link'  # map -> camera_link -> optical (REP-103)
        np.testing.assert_allclose(_lookup(tree, 'map', 'camera_optical_frame'), k['pose'], atol=1e-9)
    for s, q, _ in msgs['/novel_view/query']:
        tree = _tf_tree([dynamic[s]])
        np.testing.assert_allclose(
            _lookup(tree, 'map', 'novel_view_optical'), msg_utils.pose_stamped_to_matrix(q), atol=1e-9
        )
    # Points: the same core function from the bag's own keyframe topics, and on the depth map.
    assert [s for s, _, _ in msgs['/keyframes/points']] == sorted(kf)
    for s, m, _ in msgs['/keyframes/points']:
        k = kf[s]
        assert m.header.frame_id == 'map'
        xyz, rgb = msg_utils.cloud_to_points(m)
        want = keyframe_points(k['depth'], k['rgb'], k['cam'], k['pose'], k['conf'], cfg.viz.cloud)
        np.testing.assert_array_equal(xyz, want[0])
        np.testing.assert_array_equal(rgb, want[1])
        assert 300 < len(xyz) <= cfg.viz.cloud.max_points
        u, v, z = k['cam'].pixels_of(xyz, k['pose'])
        assert len(z) == len(xyz)
        np.testing.assert_allclose(z, k['depth'][v, u], rtol=1e-4)
        np.testing.assert_array_equal(rgb, k['rgb'][v, u])
        assert (k['conf'][v, u] >= cfg.viz.cloud.min_confidence).all()
    # Poses and frustums: whole and latched, the last holds every keyframe (+ the last novel view).
    poses = msgs['/keyframes/poses'][-1][1]
    assert len(poses.poses) == len(kf)
    for p, k in zip(poses.poses, (kf[s] for s in sorted(kf))):
        np.testing.assert_allclose(msg_utils.pose_to_matrix(p), k['pose'], atol=1e-9)
    markers = msgs['/keyframes/frustums'][-1][1].markers
    assert [(m.ns, m.id) for m in markers] == [('keyframes', i) for i in range(len(kf))] + [('novel_view', 0)]
    for m, s in zip(markers, sorted(kf)):
        assert (m.type, m.action, m.header.frame_id) == (5, 0, 'map')
        assert len(m.points) % 2 == 0
        assert m.scale.x > 0
        assert m.color.a > 0
        first = m.points[0]
        np.testing.assert_allclose([first.x, first.y, first.z], kf[s]['pose'][:3, 3], atol=1e-9)
    # The novel view over slow links: a JPEG of the same image.
    for (_, raw, _), (_, jpeg, _) in zip(msgs['/novel_view/image'], msgs['/novel_view/image/compressed']):
        assert jpeg.format == 'rgb8; jpeg compressed bgr8'
        diff = np.abs(msg_utils.compressed_image_to_numpy(jpeg).astype(int) - msg_utils.image_to_rgb(raw))
        assert diff.mean() < 8


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
    # The mcap reader alone (mcap-ros2-support decodes with the ros2msg schemas in the file, as
    # Foxglove does): the viewer topics are complete.
    from mcap_ros2.decoder import DecoderFactory

    with (processed / 'bag' / 'bag_0.mcap').open('rb') as f:
        decoded = {
            c.topic: m
            for _, c, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
        }
    assert decoded['/tf_static'].transforms[0].header.frame_id == 'map'
    assert decoded['/keyframes/frustums'].markers[-1].ns == 'novel_view'
    assert decoded['/keyframes/points'].fields[3].name == 'rgb'
    assert decoded['/keyframes/poses'].poses


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
    assert 'at least sfm_min_keyframes = 4' in run(str(no_pose), '--out', str(tmp_path / 'o1'))
    off = tmp_path / 'off.yaml'
    off.write_text('depth_refiner:\n  ros__parameters:\n    sfm_mode: "off"\n')
    assert 'no pose topic' in (err := run(str(no_pose), '--out', str(tmp_path / 'o1'), '--params', str(off)))
    assert 'sfm_mode is off' in err
    off.write_text('frame_subsampler:\n  ros__parameters:\n    pose_source: topic\n')
    assert "pose_source is 'topic'" in run(str(no_pose), '--out', str(tmp_path / 'o1'), '--params', str(off))
    off.write_text('depth_refiner:\n  ros__parameters:\n    sfm_scale: depth\n')
    assert 'sfm_scale_m must be > 0' in run(str(flight), '--out', str(tmp_path / 'o1'), '--params', str(off))
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


# ------------------------------------------------------------------------------------ GPS passthrough

NAVSAT_IN = '/mavros/global_position/global'  # not the layout's name: renamed to /gps/fix
NAVSATFIX = 'sensor_msgs/msg/NavSatFix'


def _gps_fixes(start_ns: int) -> list[msg_utils.GeoFix]:
    """Fixes in the flight's first second as a drone records them: fixes with SBAS, covariance and a
    service, one without a fix (NaN altitude), one at a frame's stamp, the last recorded late."""
    cov = np.diag([4.0, 4.0, 9.0])
    fixes = [
        msg_utils.GeoFix(
            start_ns + 125_000_000 * i, 'gps_link', 50.8225 + 1e-5 * i, -0.1372 - 2e-5 * i, 40.0 + 0.5 * i,
            status=1 if i % 2 else 0, covariance=cov * (i + 1), covariance_type=2, service=1,
        )
        for i in range(6)
    ]  # fmt: skip
    fixes[3] = msg_utils.GeoFix(fixes[3].stamp_ns, 'gps_link', 0.0, 0.0, float('nan'), status=-1)
    fixes.append(msg_utils.GeoFix(start_ns + 60_000_000, 'gps_link', 50.8224, -0.1371, 39.5))
    return fixes


@pytest.fixture(scope='module')
def gps_flight(flight, tmp_path_factory) -> Path:
    """The flight with a NavSatFix topic: :func:`_gps_fixes` and one that does not convert (NaN latitude).

    Every message logged at its header stamp but the last fix, recorded after the others."""
    out = tmp_path_factory.mktemp('gps') / 'flight'
    with open_bag(flight) as reader, BagWriter(out) as writer:
        fixes = _gps_fixes(reader.start_ns)
        bad = msg_utils.GeoFix(reader.start_ns + 900_000_000, 'gps_link', float('nan'), 0.0, 0.0, status=-1)
        rows = [(m.timestamp_ns, m.topic, m.msgtype, m.rawdata) for m in reader.messages()]
        for f in (*fixes[:-1], bad):
            raw = TYPESTORE.serialize_cdr(msg_utils.fix_to_navsatfix(f, flavor='rosbags'), NAVSATFIX)
            rows.append((f.stamp_ns, NAVSAT_IN, NAVSATFIX, raw))
        rows.sort(key=lambda r: r[0])
        late = msg_utils.fix_to_navsatfix(fixes[-1], flavor='rosbags')
        rows.append((bad.stamp_ns + 1, NAVSAT_IN, NAVSATFIX, TYPESTORE.serialize_cdr(late, NAVSATFIX)))
        for t, topic, msgtype, raw in rows:
            writer.write_raw(topic, msgtype, raw, t)
    return out


def test_gps_fixes_pass_through_to_the_output_bag(gps_flight, params, tmp_path):
    """Every NavSatFix that converts, as recorded (also without a fix), on the layout's /gps/fix in
    stamp order among the other messages, readable with rosbags and the mcap reader alone."""
    import json

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader

    out = tmp_path / 'run'
    assert main(['process', str(gps_flight), '--out', str(out), '--params', str(params), *RUN]) == 0
    with open_bag(gps_flight) as reader:
        expected = sorted(_gps_fixes(reader.start_ns), key=lambda f: f.stamp_ns)
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['topics']['navsat'] == NAVSAT_IN
    assert summary['sfm'] is None  # a posed bag: GPS not used, passed through all the same
    assert summary['frames']['navsat'] == len(expected) + 1
    assert summary['frames']['bad']['navsat'] == 1  # NaN latitude: counted, not written
    assert 'navsat (no fix or altitude)' not in summary['frames']['bad']  # only counted for SfM
    assert summary['output']['topics']['/gps/fix'] == len(expected) == 7
    with open_bag(out / 'bag') as reader:
        info = reader.topics['/gps/fix']
        assert info.msgtype == NAVSATFIX
        assert info.offered_qos == (OfferedQos('best_effort', 'volatile', depth=5),)
        assert NAVSAT_IN not in reader.topics
        rows = [(m.topic, m.timestamp_ns, m.msg) for m in reader.messages()]
    got = [(t, msg_utils.navsatfix_to_fix(m)) for topic, t, m in rows if topic == '/gps/fix']
    assert [f for _, f in got] == expected  # every field, NaN altitude included
    assert [t for t, _ in got] == [f.stamp_ns for f in expected]
    log_times = [t for _, t, _ in rows]
    assert log_times == sorted(log_times)  # interleaved in time order with the keyframes
    assert rows[-1][0] != '/gps/fix'  # the keyframes go on after the fixes' first second
    at_first_frame = [topic for topic, t, _ in rows if t == expected[0].stamp_ns]
    assert at_first_frame[-1] == '/gps/fix'  # after the messages of a keyframe at its stamp
    with Reader(out / 'bag') as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        conn = next(c for c in reader.connections if c.topic == '/gps/fix')
        lats = [TYPESTORE.deserialize_cdr(raw, NAVSATFIX).latitude for _, _, raw in reader.messages([conn])]
    assert counts['/gps/fix'] == 7
    assert lats == [f.latitude_deg for f in expected]
    with (out / 'bag' / 'bag_0.mcap').open('rb') as f:
        decoded = [
            m
            for _, c, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
            if c.topic == '/gps/fix'
        ]
    assert [(m.latitude, m.longitude, m.status.status) for m in decoded] == [
        (f.latitude_deg, f.longitude_deg, f.status) for f in expected
    ]


def test_gps_read_in_every_mode_used_by_sfm_only_with_gps(gps_flight, params):
    """The fixes are read with or without poses and with --no-gps; SfM gets the usable ones with GPS on."""
    from ibr_ros.jobs.process.frames import subsample
    from ibr_ros.jobs.process.params import process_configs

    def run(**kw):
        o = ProcessOptions(params=params, **kw)
        return subsample(gps_flight, process_configs(load_params(params), o), o, None)

    posed, sfm, no_gps = run(), run(sfm=True), run(sfm=True, gps=False)
    for sub in (posed, sfm, no_gps):
        assert len(sub.navsat) == 7
        assert sub.topics['navsat'] == NAVSAT_IN
        assert sub.bad['navsat'] == 1
    assert posed.fixes == no_gps.fixes == []
    assert len(sfm.fixes) == 6  # not the one without a fix
    assert sfm.bad['navsat (no fix or altitude)'] == 1
    assert 'navsat (no fix or altitude)' not in no_gps.bad


# ------------------------------------------------------------------------------------ SfM mode


def _poses(bag: Path) -> dict[int, np.ndarray]:
    with open_bag(bag) as reader:
        return {
            m.header_stamp_ns: msg_utils.pose_stamped_to_matrix(m.msg)
            for m in reader.messages([TOPICS['pose']])
        }


@pytest.fixture(scope='module')
def sfm_processed(flight, params, tmp_path_factory) -> Path:
    """The flight without its pose topic, processed with the default sfm_mode (auto)."""
    root = tmp_path_factory.mktemp('sfm')
    _copy_topics(flight, root / 'no_pose', [TOPICS['image'], TOPICS['camera_info']], 12)
    out = root / 'run'
    args = ['process', str(root / 'no_pose'), '--out', str(out), '--params', str(params), '--views', '3']
    assert main([*args, '--no-progress']) == 0
    return out


def test_sfm_poseless_bag_registered_and_refined(sfm_processed, flight):
    import json

    summary = json.loads((sfm_processed / 'summary.json').read_text())
    sfm = summary['sfm']
    assert summary['topics']['pose'] is None
    assert sfm['why'] == 'no pose topic'
    assert sfm['keyframes'] == 6  # 12 frames at 2 fps, the sharpest of every 1 s window
    assert sfm['registered'] == summary['keyframes'] == summary['refined'] >= 5
    assert len(sfm['dropped']) == sfm['keyframes'] - sfm['registered']
    assert (sfm['frame'], sfm['frame_id'], sfm['metric'], sfm['gps']) == ('sfm', 'sfm', False, None)
    assert sfm['mean_reprojection_error_px'] < 1.0
    assert summary['views_answered'] == 3
    first = (sfm_processed / 'summary.md').read_text().split('## Details')[0]  # what a user must know first
    assert f'**registered**: {sfm["registered"]}/6 keyframes' in first
    assert '**GPS alignment**: none' in first
    assert f'**refined**: {summary["refined"]}/{summary["keyframes"]} keyframes' in first
    assert '**answered**: 3/3 novel views (valid fraction ' in first
    assert '**warnings**' in first
    msgs = _messages(sfm_processed / 'bag')
    n = summary['keyframes']
    per_keyframe = ('image', 'camera_info', 'pose', 'depth', 'depth_info', 'confidence')
    refined = len(msgs['/keyframes/depth'])
    assert {t: len(v) for t, v in msgs.items()} == {
        **{t: n for k, (t, _) in OUT_TOPICS.items() if k in per_keyframe},
        '/novel_view/query': 3, '/novel_view/image': 3, '/novel_view/camera_info': 3, '/novel_view/status': 3,
        '/novel_view/image/compressed': 3, '/keyframes/points': refined, '/keyframes/poses': n,
        '/tf_static': n, '/keyframes/frustums': n + 3, '/tf': n + 3,
    }  # fmt: skip
    assert {m.header.frame_id for _, m, _ in msgs['/keyframes/pose'] + msgs['/novel_view/query']} == {'sfm'}
    # SfM's refined camera, undistorted: a pinhole without distortion, the same for every keyframe.
    cams = [msg_utils.camera_info_to_pinhole(m) for _, m, _ in msgs['/keyframes/camera_info']]
    assert all(not c.is_distorted and np.allclose(c.k, cams[0].k) for c in cams)
    assert abs(cams[0].fx / sfm['camera_prior']['fx'] - 1) < 0.05
    # Gauge of the sfm frame: unit = the distance between the first two keyframes.
    t_wc = [msg_utils.pose_stamped_to_matrix(m) for _, m, _ in msgs['/keyframes/pose']]
    assert abs(np.linalg.norm(t_wc[1][:3, 3] - t_wc[0][:3, 3]) - 1.0) < 1e-6
    # Depth against the ground truth after a similarity fit of the SfM centres to the true ones.
    truth_poses = _poses(flight)
    stamps = [s for s, _, _ in msgs['/keyframes/pose']]
    fit = umeyama(np.array([t[:3, 3] for t in t_wc]), np.array([truth_poses[s][:3, 3] for s in stamps]))
    scale = float(np.cbrt(np.linalg.det(fit[:3, :3])))
    gt = GroundTruthRenderer(flight)
    for (stamp, depth_msg, _), cam in zip(msgs['/keyframes/depth'], cams, strict=True):
        truth = gt.render(truth_poses[stamp], cam)
        d = msg_utils.image_to_numpy(depth_msg) * scale
        ok = np.isfinite(truth.depth) & np.isfinite(d)
        assert ok.mean() > 0.5
        assert np.median(np.abs(d[ok] - truth.depth[ok]) / truth.depth[ok]) < 0.1, stamp


def test_sfm_forced_on_posed_bag_evaluates_against_its_poses(flight, params, tmp_path):
    options = ProcessOptions(params=params, sfm=True, max_keyframes=4, views=1)
    summary = process_bag(flight, tmp_path / 'forced', options)
    assert summary['sfm']['why'] == '--sfm'
    assert summary['sfm']['registered'] == summary['refined'] == 4
    gt = summary['ground_truth']
    assert gt['sfm_alignment']['rotation_rms_deg'] < 1.0
    assert gt['sfm_alignment']['centre_rms_m'] < 1.0  # the orbit's keyframes are ~8 m apart
    assert gt['depth_median_abs_rel'] < 0.1
    assert 'SfM poses fitted' in (tmp_path / 'forced' / 'summary.md').read_text()


def test_sfm_brighton_beach_gps_enu(repo, tmp_path):
    """Real photos with GPS: registered in ENU metres, poses in frame map, ~40 m depth (nadir at ~40 m)."""
    import json

    params = tmp_path / 'spread.yaml'
    params.write_text('frame_subsampler:\n  ros__parameters:\n    poseless_interval_s: 20.0\n')
    out = tmp_path / 'brighton'
    args = ['process', str(repo / 'bags' / 'brighton_beach'), '--out', str(out), '--params', str(params)]
    assert main([*args, '--views', '1', '--no-progress']) in (0, 1)
    summary = json.loads((out / 'summary.json').read_text())
    sfm = summary['sfm']
    keys = ('keyframes', 'registered', 'dropped', 'mean_reprojection_error_px')
    print('brighton SfM:', {k: sfm[k] for k in keys}, sfm['gps'], summary['timings_s']['total'])
    assert sfm['keyframes'] == 7
    assert 5 <= sfm['registered'] == summary['keyframes']
    assert (sfm['frame'], sfm['frame_id'], sfm['metric'], sfm['unit']) == ('enu', 'map', True, 'm')
    assert sfm['gps']['topic'] == '/gps/fix'
    assert sfm['gps']['keyframes_with_gps'] == 7
    assert sfm['gps']['alignment_rms_m'] < 3.0
    assert sfm['mean_reprojection_error_px'] < 1.0
    assert 30.0 < sfm['scene_depth_from_sparse_points'] < 50.0
    assert summary['refined'] >= 3
    msgs = _messages(out / 'bag')
    assert {m.header.frame_id for _, m, _ in msgs['/keyframes/pose']} == {'map'}
    # the flight's 18 fixes for the map panel, as recorded
    with open_bag(repo / 'bags' / 'brighton_beach') as reader:
        fixes = [msg_utils.navsatfix_to_fix(m.msg) for m in reader.messages(['/gps/fix'])]
    assert [msg_utils.navsatfix_to_fix(m) for _, m, _ in msgs['/gps/fix']] == fixes
    assert summary['output']['topics']['/gps/fix'] == len(fixes) == 18
    dropped = {int(s) for s in sfm['dropped']}
    assert not dropped & {s for s, _, _ in msgs['/keyframes/image']}
    for _, m, _ in msgs['/keyframes/pose']:
        t_wc = msg_utils.pose_stamped_to_matrix(m)
        assert t_wc[2, 2] < -0.9  # nadir: the optical axis points down in ENU
    depth = np.concatenate([msg_utils.image_to_numpy(m).ravel() for _, m, _ in msgs['/keyframes/depth']])
    assert 30.0 < np.nanmedian(depth) < 50.0


# ------------------------------------------------------------------------------------ target_keyframes


def test_target_keyframes(flight, params, tmp_path):
    """``--target-keyframes 10`` (over the params file's 3): select_keyframes over the whole 12-frame
    flight, about 10 keyframes, all refined and rendered; the summary names the selection and its scale.
    """
    import json

    params.with_name('target.yaml').write_text(PARAMS + '    target_keyframes: 3\n')
    out = tmp_path / 'target'
    args = ['process', str(flight), '--out', str(out), '--params', str(params.with_name('target.yaml'))]
    assert main([*args, '--target-keyframes', '10', '--views', '2', '--no-progress']) == 0
    summary = json.loads((out / 'summary.json').read_text())
    sel, n = summary['keyframe_selection'], summary['keyframes']
    assert (sel['method'], sel['target'], sel['frames'], sel['selected']) == ('select_keyframes', 10, 12, n)
    assert abs(n - 10) <= 2
    assert sel['scale'] < 1.0  # smaller baselines than scene_depth_m 80 x baseline_ratio: more keyframes
    assert sel['baseline_ratio'] == pytest.approx(0.08 * sel['scale'])
    assert summary['refined'] == n
    assert summary['views_answered'] == 2
    assert sum(summary['frames']['decisions'].values()) == 12
    assert (
        f'select_keyframes over the whole flight, target 10: {n} of 12 frames'
        in (out / 'summary.md').read_text()
    )
    # The second pass kept the chosen frames' own images.
    msgs = _messages(out / 'bag')
    with open_bag(flight) as reader:
        jpeg = {m.header_stamp_ns: m.msg for m in reader.messages([TOPICS['image']])}
    assert len(msgs['/keyframes/image']) == n
    for stamp, msg, _ in msgs['/keyframes/image']:
        np.testing.assert_array_equal(
            msg_utils.image_to_rgb(msg), msg_utils.compressed_image_to_numpy(jpeg[stamp])
        )


def test_target_keyframes_two_passes_skip_bad_images(flight, tmp_path):
    """The second pass assembles frames as the first (undecodable images included) and decodes only the
    chosen ones; ``--max-keyframes`` keeps the first of them; a negative target is a user error.
    """
    from ibr_ros.jobs.process import process_configs, subsample

    bag = tmp_path / 'garbled'
    with open_bag(flight) as reader, BagWriter(bag) as writer:
        images = 0
        for m in reader.messages([TOPICS['image'], TOPICS['camera_info'], TOPICS['pose']]):
            images += m.topic == TOPICS['image']
            if m.topic == TOPICS['image'] and images in (3, 8):
                m.msg.data = np.frombuffer(b'not a jpeg', np.uint8)
                writer.write(m.topic, m.msg, m.timestamp_ns)
            else:
                writer.write_raw(m.topic, m.msgtype, m.rawdata, m.timestamp_ns)
    o = ProcessOptions(target_keyframes=6)
    sub = subsample(bag, process_configs(load_params(), o), o, None)
    assert sub.bad['image'] == 2
    assert sub.counts['frames'] == 10
    assert sub.selection['method'] == 'select_keyframes'
    assert abs(len(sub.keyframes) - 6) <= 2
    assert [k.stamp for k in sub.keyframes] == sorted(k.stamp for k in sub.keyframes)
    with open_bag(flight) as reader:
        jpeg = {m.header_stamp_ns: m.msg for m in reader.messages([TOPICS['image']])}
    for k in sub.keyframes:
        np.testing.assert_array_equal(k.rgb, msg_utils.compressed_image_to_numpy(jpeg[k.stamp]))
    o = ProcessOptions(target_keyframes=6, max_keyframes=2)
    first = subsample(bag, process_configs(load_params(), o), o, None)
    assert [k.stamp for k in first.keyframes] == [k.stamp for k in sub.keyframes[:2]]
    assert first.stopped
    with pytest.raises(UserError, match='target_keyframes'):
        process_configs(load_params(), ProcessOptions(target_keyframes=-1))


def test_progress_reports_every_stage_to_its_total(flight, params, tmp_path):
    """Each stage's bar (``ibr process`` draws one per stage, with an ETA) ends at its total, in order."""
    seen: dict[str, tuple[int, int]] = {}
    order: list[str] = []

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in seen:
            order.append(stage)
        assert done <= total
        seen[stage] = (done, total)

    options = ProcessOptions(params=params, max_keyframes=3, views=2)
    s = process_bag(flight, tmp_path / 'out', options, progress)
    assert order == ['frames', 'keyframes', 'model', 'views', 'write', 'previews']
    assert seen['keyframes'] == (s['refined'], 3)
    assert seen['model'] == (s['refined'], s['refined'])
    assert seen['views'] == (2, 2)
    assert seen['write'] == (3 + 2, 3 + 2)  # keyframes and views
    assert seen['previews'] == (3 + 2, 3 + 2)


def test_interrupted_run_leaves_no_output_and_no_spilled_arrays(flight, params, tmp_path, monkeypatch):
    import ibr_ros.jobs.process as process

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(process, 'render_all', interrupted)
    with pytest.raises(KeyboardInterrupt):
        process_bag(flight, tmp_path / 'out', ProcessOptions(params=params, max_keyframes=3, views=1))
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no out, no .out.spill-*, no .out.partial-*
