# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Resilience: every node gets 1000 malformed messages interleaved with valid ones.

frame_subsampler, depth_refiner and view_renderer run in this process: one executor thread spins
the node under test and a feeder node. The feeder publishes one message at a time and waits until
the node's subscription callback returned (the test wraps the callbacks to count them), so nothing
is dropped, not even on the best-effort camera topics, and every run is the same. bag_player runs as
its own process on a bag with 1000 undecodable CDR payloads among valid messages.

The malformed messages come from seeded generators cycling through the defect kinds: wrong image
encoding, step or data size, uncalibrated camera_info, camera_info of another size than its image,
NaN pose, zero quaternion and stale stamps (a lone message older than the frames already matched);
for the renderer also wrong depth encoding, size or shape, a keyframe in another frame, and queries
with a NaN position, a zero quaternion, a pose far outside the model or another frame (stamps are
only ids to the renderer, which takes keyframes in any order, so it has no stale kind). Each
malformed message has a stamp of its own; its valid companions (a mismatched frame's image and pose)
are not counted as bad. A stale message is counted (reason ``incomplete``) when its frame is given
up: by the subsampler as soon as a newer frame completes, by the refiner only when it is evicted from
its ``max_pending`` waiting frames, so up to that many are still uncounted at the end.

Checks per node: it is still spinning, its ``BadInput`` counters hold every bad message under the
expected reason, the 'rejected input' warnings are throttled (a few lines, not 1000), and the output
for the valid messages is right: the subsampler's keyframes are those its selector picks from the
valid stream alone, the refiner's depth is close to the ground truth, and the renderer answers every
valid query with the image an in-process renderer of the same valid keyframes gives, stamped with
the query's stamp, and every query, valid or not, with one ``novel_view/status``: answered with that
render's valid fraction, or refused with the reason it was counted under. The bag_player must
publish only the decodable messages (byte-identical, in order), count and log the undecodable ones
(throttled, with a total) and exit 0.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from node_harness import (
    InProcess,
    image_msg,
    in_process,
    info_msg,
    keyframe_topics,
    pose_msg,
    resized,
    shipped_frames,
    spin_until,
)
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

import msg_utils
from ibr_ros.bag import BagWriter, open_bag
from ibr_ros.core.flight.keyframes import KeyframeSelector, blur_px
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import matrix_from_rt
from ibr_ros.core.render.renderer import NovelViewRenderer, SourceView
from ibr_ros.nodes.common import model_qos, reliable_qos

pytestmark = pytest.mark.dds

N_BAD = 1000
FRAMES = 120  # the bag's first 12 s (10 fps)
ODD = ('yuv422_garbage', '32FC1', '16UC1', '', 'jpeg', 'rgb16')
PIPE_QOS = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)
FEEDER = 'resilience_feeder'
LOG_LINE = re.compile(r'rejected input \((\w+), ')


# ------------------------------------------------------------------------------------ data


@pytest.fixture(scope='module')
def bag(repo) -> dict[int, dict]:
    """Frames 0..FRAMES-1 of the shipped bag: stamp, rgb, camera, pose, and ground-truth depth (every 3rd)."""
    return dict(enumerate(shipped_frames(repo, range(FRAMES))))


# ------------------------------------------------------------------------------- defects


def bad_image(kind: str, rng: np.random.Generator, rgb: np.ndarray, stamp: int) -> Image:
    """An rgb8 image of ``rgb`` with a wrong ``encoding``, ``step`` or data ``size``."""
    h, w = rgb.shape[:2]
    if kind == 'size':  # fewer rows of data than height x step
        msg = image_msg(rgb[: int(rng.integers(0, h))], stamp)
        msg.height = h
        return msg
    msg = image_msg(rgb, stamp)
    if kind == 'encoding':
        msg.encoding = str(rng.choice(ODD))
    else:  # step shorter than a row, or longer than the data holds
        msg.step = int(rng.integers(1, 3 * w)) if rng.random() < 0.5 else 3 * w + 4 * int(rng.integers(1, 9))
    return msg


def bad_info(rng: np.random.Generator, cam: PinholeCamera, stamp: int) -> CameraInfo:
    """A camera_info that describes no camera: K all zeros or not finite, or a zero size."""
    msg = info_msg(cam, stamp)
    v = int(rng.integers(3))
    if v == 0:
        msg.k = [0.0] * 9
    elif v == 1:
        k = list(msg.k)
        k[int(rng.integers(9))] = float(rng.choice([np.nan, np.inf]))
        msg.k = k
    else:
        msg.width = 0
    return msg


def bad_pose(kind: str, rng: np.random.Generator, t_wc: np.ndarray, stamp: int) -> PoseStamped:
    """A pose with a NaN (or inf) component, or a zero quaternion."""
    msg = pose_msg(t_wc, stamp)
    if kind == 'zero_quaternion':
        q = msg.pose.orientation
        q.x = q.y = q.z = q.w = 0.0
    else:
        part = msg.pose.position if rng.random() < 0.5 else msg.pose.orientation
        axes = ('x', 'y', 'z') if part is msg.pose.position else ('x', 'y', 'z', 'w')
        setattr(part, str(rng.choice(axes)), float(rng.choice([np.nan, np.inf, -np.inf])))
    return msg


def lone(which: str, f: dict, stamp: int) -> Image | CameraInfo | PoseStamped:
    """The valid ``which`` ('image', 'info' or 'pose') message of frame ``f``, stamped ``stamp``."""
    if which == 'image':
        return image_msg(f['rgb'], stamp)
    return info_msg(f['camera'], stamp) if which == 'info' else pose_msg(f['pose'], stamp)


def spread(n_bad: int, n_gaps: int) -> list[int]:
    """How many bad messages go into each of ``n_gaps`` gaps between valid messages."""
    return [len(a) for a in np.array_split(np.arange(n_bad), n_gaps)]


# ------------------------------------------------------------------------------------- log


def check_log(text: str, counters: list[Counter], seconds: float, throttle_s: float) -> None:
    """The warnings name every counted reason, each at most once per counter and throttle period."""
    lines = Counter(LOG_LINE.findall(text))
    counted = Counter(r for c in counters for r, n in c.items() if n > 0)  # reason -> counters using it
    assert set(lines) == set(counted), (lines, counters)
    periods = 1 + math.ceil(seconds / throttle_s)
    assert all(n <= periods * counted[r] for r, n in lines.items()), (lines, seconds)


def by_reason(sent: Counter[str], reason_of: dict[str, str]) -> Counter[str]:
    """What the node should count per reason for the N_BAD messages ``sent`` (per kind)."""
    assert sum(sent.values()) == N_BAD
    want: Counter[str] = Counter()
    for kind, n in sent.items():
        want[reason_of[kind]] += n
    return want


# ---------------------------------------------------------------------------------- feeding


def send_frame(h: InProcess, pubs: dict, f: dict, stamp: int, order: tuple[str, ...], *,
               cam: PinholeCamera | None = None, frame_id: str = 'map') -> None:  # fmt: skip
    """Frame ``f``'s valid image, camera_info (or ``cam``) and pose, stamped ``stamp``, in ``order``."""
    msgs = {
        'image': image_msg(f['rgb'], stamp),
        'info': info_msg(cam or f['camera'], stamp),
        'pose': pose_msg(f['pose'], stamp, frame_id),
    }
    for which in order:
        h.send(pubs[which], msgs[which])


def send_defect(h: InProcess, pubs: dict, kind: str, rng: np.random.Generator, f: dict, stamp: int) -> bool:
    """Whether ``kind`` is a defect of an image, camera_info or pose; if so, frame ``f``'s one is sent."""
    if kind in ('encoding', 'step', 'size'):
        h.send(pubs['image'], bad_image(kind, rng, f['rgb'], stamp))
    elif kind == 'uncalibrated':
        h.send(pubs['info'], bad_info(rng, f['camera'], stamp))
    elif kind in ('nan_pose', 'zero_quaternion'):
        h.send(pubs['pose'], bad_pose(kind, rng, f['pose'], stamp))
    else:
        return False
    return True


def feed(h: InProcess, pubs: dict, frames: list[dict], kinds: tuple[str, ...], rng: np.random.Generator,
         order: tuple[str, ...], stale: Callable[[dict, int, int], int]) -> Counter[str]:  # fmt: skip
    """Send ``frames`` (their messages in ``order``) with N_BAD malformed messages spread between them.

    The defects cycle through ``kinds`` (of :data:`SUB_KINDS`); bad message ``n`` after frame ``f`` is
    stamped between ``f`` and the next frame, except a stale one: ``stale(f, n, j)`` with ``j`` the
    number of bad messages so far. Returns how many of each kind were sent.
    """
    sent: Counter[str] = Counter()
    j = 0
    for k, f in enumerate(frames):
        send_frame(h, pubs, f, f['stamp'], order)
        if k == len(frames) - 1:
            break
        for n in range(spread(N_BAD, len(frames) - 1)[k]):
            kind = kinds[j % len(kinds)]
            j += 1
            sent[kind] += 1
            stamp = f['stamp'] + 1000 * (n + 1)  # between this frame and the next
            if send_defect(h, pubs, kind, rng, f, stamp):
                continue
            if kind == 'mismatch':  # a complete frame whose camera_info is twice the image size
                send_frame(h, pubs, f, stamp, order, cam=f['camera'].scaled(2.0))
            else:
                old = stale(f, n, j)
                which = ('image', 'info', 'pose')[int(rng.integers(3))]
                h.send(pubs[which], lone(which, f, old))
    return sent


# -------------------------------------------------------------------------- frame_subsampler

SUB_KINDS = ('encoding', 'step', 'size', 'uncalibrated', 'mismatch', 'nan_pose', 'zero_quaternion', 'stale')
SUB_REASON = {
    'encoding': 'image',
    'step': 'image',
    'size': 'image',
    'uncalibrated': 'camera_info',
    'mismatch': 'camera_info',
    'nan_pose': 'pose',
    'zero_quaternion': 'pose',
    'stale': 'incomplete',  # waits in the pending frames until a newer frame completes
}


def test_frame_subsampler_survives_1000_bad_messages(repo, bag, capfd):
    from ibr_ros.nodes.frame_subsampler import FrameSubsampler

    frames = [resized(bag[i], (160, 90)) for i in range(0, FRAMES, 2)]  # 60 frames, 5 fps
    rng = np.random.default_rng(1)
    config = repo / 'config' / 'frame_subsampler.yaml'
    with in_process(FrameSubsampler, config, FEEDER, scene_depth_m=120.0) as h:
        node = h.node
        keyframes = {
            k: h.collect(cls, f'keyframes/{k}', model_qos())
            for k, cls in (('image', Image), ('camera_info', CameraInfo), ('pose', PoseStamped))
        }
        pubs = h.publishers({
            'image': (Image, 'camera/image_raw', PIPE_QOS),
            'info': (CameraInfo, 'camera/camera_info', PIPE_QOS),
            'pose': (PoseStamped, 'camera/pose', PIPE_QOS),
        })  # fmt: skip
        capfd.readouterr()
        t0 = time.monotonic()
        # A stale message: a lone valid one older than the frame just matched.
        sent = feed(h, pubs, frames, SUB_KINDS, rng, ('info', 'pose', 'image'),
                    stale=lambda f, n, j: f['stamp'] - 50_000_000 - 1000 * n)  # fmt: skip
        # Keyframes of the valid stream alone, by the node's own selection policy.
        selector = KeyframeSelector(node.config)
        expected = [
            f['stamp']
            for f in frames
            if selector.decide(f['stamp'], f['pose'], blur_px(f['rgb']), node.scene_depth or None).keep
        ]
        assert h.wait(lambda: all(len(b) >= len(expected) for b in keyframes.values()), 20), (
            {k: len(b) for k, b in keyframes.items()},
            len(expected),
        )
        assert h.alive, h.error
        seconds = time.monotonic() - t0
        counts = Counter(node.bad.counts)
        throttle_s = node.bad.throttle_s
    log = capfd.readouterr().err
    want = by_reason(sent, SUB_REASON)
    assert counts == want, f'counted {dict(counts)}, sent {dict(sent)}'
    assert 4 <= len(expected) < len(frames) // 2
    for topic, box in keyframes.items():
        assert [msg_utils.stamp_to_ns(m.header.stamp) for m in box] == expected, topic
    by_stamp = {f['stamp']: f for f in frames}
    for img, pose in zip(keyframes['image'], keyframes['pose']):
        f = by_stamp[msg_utils.stamp_to_ns(img.header.stamp)]
        np.testing.assert_array_equal(msg_utils.image_to_numpy(img), f['rgb'])
        np.testing.assert_allclose(msg_utils.pose_stamped_to_matrix(pose), f['pose'], atol=1e-9)
    check_log(log, [counts], seconds, throttle_s)


# ------------------------------------------------------------------------------ depth_refiner

REF_KINDS = SUB_KINDS
REF_KEYFRAMES = (0, 24, 48, 72, 96)


def test_depth_refiner_survives_1000_bad_messages(repo, bag, capfd):
    """Stale messages wait among the ``max_pending`` incomplete frames and are counted when evicted."""
    from ibr_ros.nodes.depth_refiner import DepthRefinerNode

    kfs = [resized(bag[i], (320, 180)) for i in REF_KEYFRAMES]
    rng = np.random.default_rng(2)
    params = {'max_neighbours': 2, 'flush_after_s': 1.0, 'max_pending': 30}
    with in_process(DepthRefinerNode, repo / 'config' / 'depth_refiner.yaml', FEEDER, **params) as h:
        node = h.node
        depths = h.collect(Image, 'keyframes/depth', model_qos())
        pubs = h.publishers(keyframe_topics(model_qos()))
        capfd.readouterr()
        t0 = time.monotonic()
        first = kfs[0]['stamp']
        # A stale message: a lone one older than every keyframe, so its frame never completes.
        sent = feed(h, pubs, kfs, REF_KINDS, rng, ('image', 'info', 'pose'),
                    stale=lambda f, n, j: first - 1_000_000_000 - 1000 * j)  # fmt: skip
        want_stamps = {f['stamp'] for f in kfs}
        assert h.wait(lambda: {msg_utils.stamp_to_ns(m.header.stamp) for m in depths} >= want_stamps, 60), [
            msg_utils.stamp_to_ns(m.header.stamp) for m in depths
        ]
        assert h.alive, h.error
        seconds = time.monotonic() - t0
        counts = Counter(node.bad.counts)
        waiting = len(node.frames)  # incomplete frames still waiting for their other messages
        throttle_s = node.bad.throttle_s
    log = capfd.readouterr().err
    want = by_reason(sent, SUB_REASON)
    # The stale frames still waiting at the end are not counted (yet); all others are.
    assert 0 < waiting <= params['max_pending']
    want['incomplete'] -= waiting
    assert counts == want, f'counted {dict(counts)}, sent {dict(sent)}, {waiting} waiting'
    stamps = [msg_utils.stamp_to_ns(m.header.stamp) for m in depths]
    assert sorted(stamps) == sorted(want_stamps), 'each valid keyframe refined exactly once'
    by_stamp = {f['stamp']: f for f in kfs}
    rels = {}
    for m in depths:
        f = by_stamp[msg_utils.stamp_to_ns(m.header.stamp)]
        assert (m.encoding, m.width, m.height) == ('32FC1', 320, 180)
        d, gt = msg_utils.image_to_numpy(m), f['gt']
        ground = np.isfinite(gt) & (gt > 0)
        ok = ground & np.isfinite(d) & (d > 0)
        assert ok.sum() > 0.9 * ground.sum()
        rels[f['stamp']] = float(np.median(np.abs(d[ok] - gt[ok]) / gt[ok]))
    assert max(rels.values()) < 0.1, rels
    check_log(log, [counts], seconds, throttle_s)


# ------------------------------------------------------------------------------ view_renderer

RND_KINDS = (
    'encoding', 'step', 'size', 'uncalibrated', 'nan_pose', 'zero_quaternion', 'depth_encoding', 'depth_size',
    'mismatch', 'depth_shape', 'frame', 'query_nan', 'query_zero_quaternion', 'query_far', 'query_frame',
)  # fmt: skip
RND_REASON = {  # (counter, reason): ``bad`` for keyframe input, ``unanswered`` for queries
    'encoding': ('bad', 'image'),
    'step': ('bad', 'image'),
    'size': ('bad', 'image'),
    'uncalibrated': ('bad', 'camera_info'),
    'nan_pose': ('bad', 'pose'),
    'zero_quaternion': ('bad', 'pose'),
    'depth_encoding': ('bad', 'depth'),
    'depth_size': ('bad', 'depth'),
    'mismatch': ('bad', 'size'),  # camera_info of another size than image and depth
    'depth_shape': ('bad', 'size'),  # depth of another size than image and camera_info
    'frame': ('bad', 'frame'),  # a keyframe pose in another frame than the model's
    'query_nan': ('unanswered', 'invalid_query'),
    'query_zero_quaternion': ('unanswered', 'invalid_query'),
    'query_far': ('unanswered', 'unrenderable'),
    'query_frame': ('unanswered', 'frame'),
}
RND_KEYFRAMES = (48, 57, 66, 75, 84, 93)
QUERIES_PER_GAP = 4


def bad_depth(kind: str, rng: np.random.Generator, depth: np.ndarray, stamp: int) -> Image:
    """A depth image with a non-depth encoding or less data than height x step."""
    header = msg_utils.make_header(stamp, 'camera_optical')
    if kind == 'depth_size':
        msg = msg_utils.numpy_to_image(depth[: int(rng.integers(0, depth.shape[0]))], '32FC1', header)
        msg.height = depth.shape[0]
        return msg
    grey = np.clip(np.nan_to_num(depth, posinf=255.0), 0, 255).astype(np.uint8)
    encoding = str(rng.choice(['rgb8', 'mono8', 'bgr8', '8UC1']))
    return msg_utils.numpy_to_image(
        np.dstack([grey] * 3) if encoding in ('rgb8', 'bgr8') else grey, encoding, header
    )


def test_view_renderer_survives_1000_bad_messages(repo, bag, capfd):
    from ibr_ros.nodes.view_renderer import ViewRenderer

    kfs = [resized(bag[i], (320, 180)) for i in RND_KEYFRAMES]
    rng = np.random.default_rng(3)
    config = repo / 'config' / 'view_renderer.yaml'
    with in_process(ViewRenderer, config, FEEDER, n_segments=400) as h:
        node = h.node
        replies = h.collect(Image, 'novel_view/image', reliable_qos())
        jpegs = h.collect(CompressedImage, 'novel_view/image/compressed', reliable_qos())
        infos = h.collect(CameraInfo, 'novel_view/camera_info', reliable_qos())
        statuses = h.collect(DiagnosticArray, 'novel_view/status', reliable_qos(1000))
        pubs = h.publishers({
            **keyframe_topics(model_qos()),
            'depth': (Image, 'keyframes/depth', model_qos()),
            'query': (PoseStamped, 'novel_view/query', reliable_qos()),
        })  # fmt: skip
        outs = [p for p in node.publishers if p.topic_name.startswith('/novel_view/')]
        assert h.wait(lambda: len(outs) == 4 and all(p.get_subscription_count() > 0 for p in outs), 30)
        capfd.readouterr()

        def keyframe(f: dict, stamp: int, *, cam=None, depth=None, frame_id: str = 'map') -> None:
            send_frame(h, pubs, f, stamp, ('image', 'info', 'pose'), cam=cam, frame_id=frame_id)
            d = f['gt'] if depth is None else depth
            h.send(pubs['depth'], msg_utils.numpy_to_image(d, '32FC1', msg_utils.make_header(stamp)))

        reference = NovelViewRenderer([], node.config)  # the valid keyframes alone
        out_cam = PinholeCamera(kfs[0]['camera'].width, kfs[0]['camera'].height, kfs[0]['camera'].k)
        expected: list[tuple[int, np.ndarray]] = []  # (query stamp, image) of every valid query
        verdicts: dict[int, tuple[str, float | None]] = {}  # query stamp -> (reason, valid fraction)
        t0 = time.monotonic()
        sent: Counter[str] = Counter()
        j = 0
        n_gaps = len(kfs) - 1
        for k, f in enumerate(kfs):
            keyframe(f, f['stamp'])
            reference.add_view(SourceView(f['rgb'], f['gt'], f['camera'], f['pose'], name=str(f['stamp']),
                                          stamp=f['stamp'] * 1e-9))  # fmt: skip
            if k == n_gaps:
                break
            n_bad = spread(N_BAD, n_gaps)[k]
            valid_at = set(rng.choice(n_bad, QUERIES_PER_GAP, replace=False)) if k >= 1 else set()
            for n in range(n_bad):
                if n in valid_at:  # a query between the keyframes in the model, a little off the flight
                    i = int(rng.choice([i for i in range(RND_KEYFRAMES[0] + 1, RND_KEYFRAMES[k])
                                        if i not in RND_KEYFRAMES]))  # fmt: skip
                    t_wc = bag[i]['pose'] @ matrix_from_rt(np.eye(3), rng.uniform(-0.5, 0.5, 3))
                    stamp = 5_000_000_000 + len(expected)
                    ref = reference.render(t_wc, out_cam)
                    assert ref.reason is None, (i, ref.reason)
                    assert ref.valid.mean() >= node.policy.min_valid_fraction, i
                    expected.append((stamp, ref.rgb))
                    verdicts[stamp] = ('', float(ref.valid.mean()))
                    h.send(pubs['query'], pose_msg(t_wc, stamp))
                kind = RND_KINDS[j % len(RND_KINDS)]
                j += 1
                sent[kind] += 1
                stamp = f['stamp'] + 1000 * (n + 1)
                g = kfs[k + 1]  # any valid frame: the defect is what counts
                if send_defect(h, pubs, kind, rng, g, stamp):
                    continue
                if kind in ('depth_encoding', 'depth_size'):
                    h.send(pubs['depth'], bad_depth(kind, rng, g['gt'], stamp))
                elif kind == 'mismatch':
                    keyframe(g, stamp, cam=g['camera'].scaled(0.5))
                elif kind == 'depth_shape':
                    keyframe(g, stamp, depth=cv2.resize(g['gt'], (160, 90), interpolation=cv2.INTER_NEAREST))
                elif kind == 'frame':
                    keyframe(g, stamp, frame_id='odom')
                else:
                    t_wc = bag[RND_KEYFRAMES[0] + 1]['pose'].copy()
                    if kind == 'query_far':
                        t_wc[:3, 3] += rng.uniform(-1, 1, 3) * 1e5
                    q = pose_msg(t_wc, stamp, 'odom' if kind == 'query_frame' else 'map')
                    if kind == 'query_nan':
                        setattr(q.pose.position, str(rng.choice(['x', 'y', 'z'])), float('nan'))
                    elif kind == 'query_zero_quaternion':
                        o = q.pose.orientation
                        o.x = o.y = o.z = o.w = 0.0
                    verdicts[stamp] = (RND_REASON[kind][1], None)
                    h.send(pubs['query'], q)
        assert h.wait(lambda: min(len(replies), len(infos), len(jpegs)) >= len(expected), 20)
        assert h.wait(lambda: len(statuses) >= len(verdicts), 20), (len(statuses), len(verdicts))
        assert h.alive, h.error
        seconds = time.monotonic() - t0
        counts = {'bad': Counter(node.bad.counts), 'unanswered': Counter(node.unanswered.counts)}
        n_model = len(node.renderer.views)
        throttle_s = node.bad.throttle_s
    log = capfd.readouterr().err
    assert sum(sent.values()) == N_BAD
    want = {'bad': Counter(), 'unanswered': Counter()}
    for kind, n in sent.items():
        counter, reason = RND_REASON[kind]
        want[counter][reason] += n
    assert counts == want, f'counted {counts}, sent {dict(sent)}'
    assert n_model == len(kfs), 'only the valid keyframes are in the model'
    assert len(expected) == QUERIES_PER_GAP * (n_gaps - 1)
    assert [msg_utils.stamp_to_ns(m.header.stamp) for m in replies] == [s for s, _ in expected]
    assert [msg_utils.stamp_to_ns(m.header.stamp) for m in infos] == [s for s, _ in expected]
    for m, (_, rgb) in zip(replies, expected):
        assert (m.encoding, m.width, m.height) == ('rgb8', 320, 180)
        np.testing.assert_array_equal(msg_utils.image_to_numpy(m), rgb)
    # The same views as JPEG (image_transport compressed) for viewers over slow links.
    assert [msg_utils.stamp_to_ns(m.header.stamp) for m in jpegs] == [s for s, _ in expected]
    for m, (_, rgb) in zip(jpegs, expected):
        assert m.format == 'rgb8; jpeg compressed bgr8'
        assert np.abs(msg_utils.compressed_image_to_numpy(m).astype(int) - rgb).mean() < 8
    got = dict(map(msg_utils.diagnostics_to_reply, statuses))
    assert len(got) == len(statuses) == len(verdicts), 'one status per query'
    for stamp, (reason, frac) in verdicts.items():
        st = got[stamp]
        assert st.reason == reason, (stamp, st)
        if reason:
            assert (st.result, st.level, st.published, st.valid_fraction) == ('refused', 'error', False, 0.0)
        else:
            assert (st.result, st.level, st.published, st.valid_fraction) == ('answered', 'ok', True, frac)
    check_log(log, [counts['bad'], counts['unanswered']], seconds, throttle_s)


# --------------------------------------------------------------------------------- bag_player

GARBAGE = ('truncated', 'random', 'encapsulation', 'string_length', 'empty')
PLAYER_TOPICS = {'/camera/image_raw': Image, '/camera/pose': PoseStamped}
N_VALID = 40  # per topic


def undecodable(data: bytes, cls: type) -> bool:
    """Whether ``data`` (zero-padded to 4 bytes, as RTPS sends it) fails to deserialise as ``cls``."""
    try:
        deserialize_message(data + b'\0' * (-len(data) % 4), cls)
    except Exception:  # rclpy raises RMWError (Fast CDR exceptions)
        return True
    return False


def garbage(kind: str, rng: np.random.Generator, valid: bytes, cls: type) -> bytes:
    """A CDR payload that does not deserialise as ``cls`` (redrawn until it does not)."""
    while True:
        if kind == 'truncated':  # at least 8 bytes short: padding cannot complete it
            data = valid[: int(rng.integers(0, len(valid) - 8))]
        elif kind == 'random':
            data = rng.bytes(int(rng.integers(1, 2 * len(valid))))
        elif kind == 'encapsulation':  # an unknown representation identifier
            data = bytes([int(rng.integers(0x10, 0x100)), int(rng.integers(0, 0x100))]) + valid[2:]
        elif kind == 'string_length':  # header.frame_id longer than the payload
            data = valid[:12] + int(rng.integers(len(valid), 2**31)).to_bytes(4, 'little') + valid[16:]
        else:
            data = b''
        if undecodable(data, cls):
            return data


@pytest.fixture
def garbage_bag(tmp_path) -> tuple[Path, dict[str, list[bytes]], int]:
    """N_VALID images and poses at 10 Hz with 1000 undecodable payloads on the same topics between them."""
    rng = np.random.default_rng(4)
    path = tmp_path / 'garbage'
    start = 1_700_000_000_000_000_000
    valid: dict[str, list[bytes]] = {t: [] for t in PLAYER_TOPICS}
    per_gap = spread(N_BAD, N_VALID - 1)
    j = 0
    with BagWriter(path) as writer:
        for i in range(N_VALID):
            stamp = start + i * 100_000_000
            rgb = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
            msgs = {
                '/camera/image_raw': image_msg(rgb, stamp),
                '/camera/pose': pose_msg(matrix_from_rt(np.eye(3), [i, 0.0, 50.0]), stamp),
            }
            for topic, msg in msgs.items():
                raw = serialize_message(msg)
                valid[topic].append(raw)
                writer.write_raw(topic, msg_utils.flavor.message_typename(msg), raw, stamp)
            if i == N_VALID - 1:
                break
            for n in range(per_gap[i]):
                topic = list(PLAYER_TOPICS)[j % 2]
                kind = GARBAGE[(j // 2) % len(GARBAGE)]
                j += 1
                data = garbage(kind, rng, valid[topic][-1], PLAYER_TOPICS[topic])
                writer.write_raw(
                    topic, msg_utils.flavor.message_typename(msgs[topic]), data, stamp + 1000 * (n + 1)
                )
    return path, valid, j


def test_bag_player_skips_1000_undecodable_payloads(ros_env, tmp_path, garbage_bag):
    path, valid, n_garbage = garbage_bag
    assert n_garbage == N_BAD
    with open_bag(path) as reader:
        assert reader.message_count == N_BAD + 2 * N_VALID
    rclpy.init()
    try:
        node = rclpy.create_node('garbage_listener')
        got: dict[str, list[bytes]] = {t: [] for t in PLAYER_TOPICS}
        qos = QoSProfile(depth=5000, reliability=QoSReliabilityPolicy.RELIABLE)
        for topic, cls in PLAYER_TOPICS.items():
            node.create_subscription(cls, topic, got[topic].append, qos, raw=True)
        log = tmp_path / 'player.log'
        argv = [sys.executable, '-m', 'ibr_ros.nodes.bag_player', '--ros-args', '-p', f'bag:={path}',
                '-p', 'rate:=0.0', '-p', 'wait_for_subscribers:=1', '-p', 'publish_clock:=false',
                '-p', 'ack_timeout_s:=2.0']  # fmt: skip
        proc = subprocess.Popen(argv, env=ros_env, stdout=log.open('w'), stderr=subprocess.STDOUT)
        try:
            spin_until(node, lambda: proc.poll() is not None, 40)
            quiet = 0
            while quiet < 3:  # what the player published (and saw acknowledged) is already here
                before = sum(map(len, got.values()))
                rclpy.spin_once(node, timeout_sec=0.05)
                quiet = quiet + 1 if sum(map(len, got.values())) == before else 0
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
    finally:
        rclpy.try_shutdown()
    out = log.read_text()
    assert proc.returncode == 0, out
    forwarded = {t: sum(undecodable(bytes(d), PLAYER_TOPICS[t]) for d in box) for t, box in got.items()}
    received = {t: len(box) - forwarded[t] for t, box in got.items()}
    assert not any(forwarded.values()), (
        f'undecodable payloads published: {forwarded}; valid ones received: {received} of {N_VALID} each\n'
        f'{out[-2000:]}'
    )
    for topic, raws in valid.items():
        assert [bytes(d)[: len(r)] for d, r in zip(got[topic], raws)] == raws, topic
        assert len(got[topic]) == len(raws), topic
    assert f'done: {2 * N_VALID} messages' in out, out
    assert 0 < len(LOG_LINE.findall(out)) < 10, out  # throttled warnings
    assert re.search(rf'\b{N_BAD}\b.*(undecodable|malformed|rejected|skipped)', out), out
