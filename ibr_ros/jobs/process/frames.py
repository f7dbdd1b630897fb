# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Reading the bag: topics, frames matched by header stamp, and the frame_subsampler's keyframes
(streaming, for a target count in two passes, or without poses per interval)."""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import msg_utils
from ibr_ros.bag import BagReader, detect_topics, open_bag
from ibr_ros.bag.detect import ODOMETRY, POSE_STAMPED
from ibr_ros.core.flight.keyframes import (
    IntervalSelector,
    KeyframeSelector,
    TargetSelection,
    blur_px,
    detail_score,
    select_keyframes_for_target,
)
from ibr_ros.core.flight.stamps import StampAssembler
from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.errors import UserError
from ibr_ros.jobs.process.options import ProcessOptions, Progress
from ibr_ros.jobs.process.params import ProcessConfigs

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules

#: :attr:`~ibr_ros.core.flight.keyframes.Pick.reason` -> the keyframe's reason without poses.
INTERVAL_REASONS = {'sharpest': 'sharpest of its window', 'overlap': 'blurred, kept for overlap'}


@dataclass
class Keyframe:
    """A selected keyframe: ``stamp`` (ns), rgb8 image, camera, camera-to-world pose, frames, reason.

    In SfM mode ``t_wc`` is NaN until registered, then SfM's (``pose_frame`` ``map`` or ``sfm``);
    ``bag_t_wc`` keeps the bag's pose at that stamp, if any (ground truth of a synthetic bag).
    """

    stamp: int
    rgb: np.ndarray
    camera: PinholeCamera
    t_wc: np.ndarray
    camera_frame: str
    pose_frame: str
    reason: str
    depth: np.ndarray | None = None  # refined, float32 metres (0 unknown, +inf sky)
    confidence: np.ndarray | None = None  # of the refined depth, float32 in [0, 1]
    neighbours: tuple[int, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)
    bag_t_wc: np.ndarray | None = None


@dataclass
class Subsampled:
    """The keyframes :func:`subsample` chose, with what it read and counted on the way."""

    keyframes: list[Keyframe]
    counts: Counter
    bad: Counter
    decisions: Counter
    topics: dict[str, str | None]
    sfm_why: str | None = None  # why SfM mode (None: the bag's poses are used)
    poseless: bool = False  # keyframes chosen without poses (IntervalSelector)
    fixes: list[msg_utils.GeoFix] = field(default_factory=list)  # for SfM: with a fix and an altitude
    stopped: bool = False  # at max_keyframes
    selection: dict[str, object] = field(default_factory=dict)  # how the keyframes were chosen
    navsat: list[msg_utils.GeoFix] = field(default_factory=list)  # every fix read, as recorded


@dataclass
class _Frame:
    """A complete frame: image (None when not decoded: not wanted), camera, its frame id, pose."""

    stamp: int
    image: np.ndarray | None
    camera: PinholeCamera
    camera_frame: str
    pose: tuple[np.ndarray, str] | None  # None without poses (SfM mode)

    @property
    def rgb(self) -> np.ndarray:
        """The decoded image (a frame that was wanted)."""
        if self.image is None:
            raise ValueError(f'frame {self.stamp} ns was not decoded')
        return self.image

    @property
    def t_wc(self) -> np.ndarray:
        """The camera-to-world pose (a flight with poses)."""
        if self.pose is None:
            raise ValueError(f'frame {self.stamp} ns has no pose')
        return self.pose[0]


@dataclass
class _Reading:
    """What one pass of :func:`_frames` counted and collected (``image_ok``: per image message, in bag
    order, whether it decoded). ``navsat``: every NavSatFix that converts, in bag order, as recorded
    (passed through to the output bag); ``fixes``: those usable for SfM (a fix and an altitude), only
    with ``gps`` (SfM mode and ``ProcessOptions.gps``).
    """

    gps: bool = False
    counts: Counter = field(default_factory=Counter)
    bad: Counter = field(default_factory=Counter)
    navsat: list[msg_utils.GeoFix] = field(default_factory=list)
    fixes: list[msg_utils.GeoFix] = field(default_factory=list)
    bag_poses: dict[int, np.ndarray] = field(default_factory=dict)
    image_ok: list[bool] = field(default_factory=list)


def _frames(
    reader: BagReader,
    topics: dict[str, str | None],
    cfg: ProcessConfigs,
    poseless: bool,
    reading: _Reading,
    progress: Progress | None,
    *,
    stage: str = 'frames',
    wanted: set[int] | None = None,
    decoded: list[bool] | None = None,
) -> Iterator[_Frame]:
    """The bag's complete frames in bag-time order: image, camera_info and (unless ``poseless``) pose
    with identical header stamps, counted into ``reading``.

    ``wanted`` (a second pass): yield only the frames with these stamps and decode only their images;
    ``decoded`` (the first pass's ``image_ok``) says which other image messages to put undecoded, so
    that the frames are assembled exactly as in the first pass.
    """
    counts, bad = reading.counts, reading.bad

    def incomplete(detail: str) -> None:
        bad['incomplete'] += 1
        LOG.debug(detail)

    fields = ('image', 'camera_info') if poseless else ('image', 'camera_info', 'pose')
    assembler = StampAssembler(fields, cfg.subsampler.max_pending, incomplete, supersede=True)
    to_pose = (
        msg_utils.odometry_to_matrix if topics['pose_type'] == ODOMETRY else msg_utils.pose_stamped_to_matrix
    )
    n_images = reader.topics[str(topics['image'])].count
    role = {str(topics[k]): k for k in ('image', 'camera_info', 'pose', 'navsat') if topics[k] is not None}
    for m in reader.messages(list(role)):
        field = role[m.topic]
        counts[field] += 1
        if field == 'image' and progress is not None:
            progress(stage, counts['image'], n_images)
        msg: Any = m.msg
        stamp = msg_utils.stamp_to_ns(msg.header.stamp)
        try:
            if field == 'image':
                if wanted is not None and stamp not in wanted:
                    ok = decoded is None or (counts['image'] <= len(decoded) and decoded[counts['image'] - 1])
                    if not ok:
                        bad[field] += 1
                        continue
                    value: object = None  # not wanted: assembled as in the first pass, not decoded
                else:
                    value = msg_utils.camera_image_to_rgb(msg)
                reading.image_ok.append(True)
            elif field == 'camera_info':
                value = (msg.header.frame_id, msg_utils.camera_info_to_pinhole(msg))
            elif field == 'navsat':
                fix = msg_utils.navsatfix_to_fix(msg)
                reading.navsat.append(fix)
                if not reading.gps:
                    continue
                if fix.status >= 0 and math.isfinite(fix.altitude_m):  # as ibr register
                    reading.fixes.append(fix)
                else:
                    bad['navsat (no fix or altitude)'] += 1
                continue
            else:
                pose = to_pose(msg)
                value = (pose, msg.header.frame_id or 'map')
        except msg_utils.CONVERSION_ERRORS as exc:
            bad[field] += 1
            if field == 'image':
                reading.image_ok.append(False)
            LOG.debug('bad %s message at %d ns: %s', field, stamp, exc)
            continue
        if field == 'pose' and poseless:  # ignored, but the ground truth of a synthetic bag
            reading.bag_poses[stamp] = pose
            continue
        if (f := assembler.put(stamp, field, value)) is None or (wanted is not None and stamp not in wanted):
            continue
        image, (camera_frame, camera) = f['image'], f['camera_info']
        if (camera.height, camera.width) != image.shape[:2]:
            bad['camera_info'] += 1
            LOG.debug(
                'CameraInfo %dx%d does not match the image at %d ns', camera.width, camera.height, stamp
            )
            continue
        counts['frames'] += 1
        yield _Frame(stamp, image, camera, camera_frame, None if poseless else f['pose'])


def _select_topics(
    reader: BagReader, o: ProcessOptions, cfg: ProcessConfigs
) -> tuple[dict[str, str | None], str | None]:
    """Image, camera_info, pose and NavSatFix topics (given or detected by type) and their types, and
    why SfM mode is used (None: it is not). The NavSatFix topic is read whenever there is one (its
    fixes go to the output bag); ``ProcessOptions.gps`` only decides whether SfM uses them.
    """
    sel = detect_topics(
        reader, image=o.image_topic, camera_info=o.info_topic, pose=o.pose_topic, navsat=o.navsat_topic
    )
    topics = reader.topics
    where = f'{reader.path}: topics: ' + ', '.join(f'{t.name} ({t.msgtype})' for t in topics.values())
    if sel.image is None:
        raise UserError(
            f'no camera image topic (sensor_msgs/msg/Image or CompressedImage; --image-topic); {where}'
        )
    if sel.camera_info is None:
        raise UserError(f'no camera_info topic (sensor_msgs/msg/CameraInfo; --info-topic); {where}')
    if sel.pose is not None and sel.pose_type not in (POSE_STAMPED, ODOMETRY):
        raise UserError(
            f'pose topic {sel.pose} is {sel.pose_type}; ibr process reads geometry_msgs/msg/PoseStamped '
            f'or nav_msgs/msg/Odometry; {where}'
        )
    no_pose = 'no pose topic (geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry; --pose-topic)'
    if o.sfm:
        why: str | None = '--sfm'
    elif cfg.subsampler.pose_source == 'none':
        why = "frame_subsampler pose_source 'none'"
    elif sel.pose is None and cfg.sfm.mode == 'off':
        raise UserError(
            f'{no_pose} and depth_refiner sfm_mode is off: frames without poses are not refined '
            f'(sfm_mode auto or --sfm registers them with SfM); {where}'
        )
    elif sel.pose is None and cfg.subsampler.pose_source == 'topic':
        raise UserError(
            f"{no_pose} and frame_subsampler pose_source is 'topic': it never selects keyframes without "
            f"poses (set it to 'auto' or pass --sfm); {where}"
        )
    elif sel.pose is None:
        why = 'no pose topic'
    else:
        why = "depth_refiner sfm_mode 'always'" if cfg.sfm.mode == 'always' else None
    out: dict[str, str | None] = {
        'image': sel.image,
        'camera_info': sel.camera_info,
        'pose': sel.pose,
        'navsat': sel.navsat,
        'image_type': topics[sel.image].msgtype,
        'pose_type': None if sel.pose is None else str(sel.pose_type),
    }
    return out, why


def subsample(
    bag: Path,
    cfg: ProcessConfigs,
    o: ProcessOptions,
    progress: Progress | None,
    spill: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Subsampled:
    """The frame_subsampler's decisions over the whole bag, in bag-time order (without poses in SfM
    mode, unless ``sfm_mode`` is ``always`` on a bag with poses); with ``target_keyframes`` and poses,
    :func:`~ibr_ros.core.flight.keyframes.select_keyframes` over the whole flight instead (two passes).
    ``spill``: where each keyframe's image goes once chosen (e.g. :meth:`SpillStore.put`).
    """
    fs = cfg.subsampler
    decisions: Counter = Counter()
    keyframes: list[Keyframe] = []

    def keep(frame: _Frame, reason: str) -> bool:
        """Append a keyframe; True when ``max_keyframes`` are there."""
        pose = frame.pose
        t_wc, pose_frame = pose if pose is not None and sfm_why is None else (np.full((4, 4), np.nan), '')
        bag_pose = pose[0] if pose is not None else reading.bag_poses.get(frame.stamp)
        camera_frame = frame.camera_frame or 'camera_optical'
        image = frame.rgb if spill is None else spill(frame.rgb)
        bag_t_wc = bag_pose if sfm_why is not None else None
        keyframes.append(
            Keyframe(
                frame.stamp, image, frame.camera, t_wc, camera_frame, pose_frame, reason, bag_t_wc=bag_t_wc
            )
        )
        return o.max_keyframes is not None and len(keyframes) >= o.max_keyframes

    stopped = False
    with open_bag(bag) as reader:
        topics, sfm_why = _select_topics(reader, o, cfg)
        reading = _Reading(gps=sfm_why is not None and o.gps)
        poseless = topics['pose'] is None or o.sfm
        frames = _frames(reader, topics, cfg, poseless, reading, progress)
        scene_depth = fs.scene_depth_m or None
        if poseless:
            if fs.target_keyframes:
                LOG.warning(
                    'target_keyframes %d ignored: keyframes chosen without poses', fs.target_keyframes
                )
            selection: dict[str, object] = {'method': 'interval', 'interval_s': fs.poseless_interval_s}
            interval: IntervalSelector[_Frame] = IntervalSelector(fs.poseless_interval_s, fs.keyframes)
            for f in frames:
                blur = blur_px(f.rgb)
                if blur > fs.keyframes.max_blur_px > 0:
                    LOG.debug('frame %d ns: blurred (%.2f px)', f.stamp, blur)
                for pick in interval.push(f.stamp, blur, f, detail=detail_score(f.rgb)):
                    stopped = stopped or keep(pick.item, INTERVAL_REASONS[pick.reason])
                if stopped:
                    break
            if not stopped:
                for pick in interval.flush():
                    keep(pick.item, INTERVAL_REASONS[pick.reason])
            for reason in INTERVAL_REASONS.values():
                decisions[f'keyframe ({reason})'] = sum(k.reason == reason for k in keyframes)
            decisions.update(interval.rejected)
            decisions['not chosen in its window'] = reading.counts['frames'] - sum(decisions.values())
            decisions = +decisions  # drop zero counts
            for k in keyframes:  # poses read after the frame's image
                if k.bag_t_wc is None and k.stamp in reading.bag_poses:
                    k.bag_t_wc = reading.bag_poses[k.stamp]
        elif fs.target_keyframes:
            # First pass: stamps, poses and blur (px) of every frame; the images are not kept.
            seen = [(f.stamp, f.t_wc, blur_px(f.rgb)) for f in frames]
            t0 = time.perf_counter()
            target = select_keyframes_for_target(
                [s for s, _, _ in seen], [p for _, p, _ in seen], [b for _, _, b in seen],
                target=fs.target_keyframes, scene_depth_m=[scene_depth] * len(seen), config=fs.keyframes,
            ) if seen else TargetSelection([], 1.0, [])  # fmt: skip
            picked, scale, decided = target.indices, target.scale, target.decisions
            decisions.update(d.reason for d in decided)
            reasons = {seen[i][0]: decided[i].reason for i in picked}
            if o.max_keyframes is not None and len(picked) > o.max_keyframes:
                picked, stopped = picked[: o.max_keyframes], True
            selection = {
                'method': 'select_keyframes',
                'target': fs.target_keyframes,
                'frames': len(seen),
                'selected': len(reasons),
                'scale': scale,
                'baseline_ratio': fs.keyframes.baseline_ratio * scale,
                'min_baseline_m': fs.keyframes.min_baseline_m * scale,
                'scene_depth_m': scene_depth,
                'seconds': time.perf_counter() - t0,
            }
            # Second pass: the chosen frames' images (the others are not decoded).
            wanted = {seen[i][0] for i in picked}
            again = _frames(
                reader, topics, cfg, poseless, _Reading(), progress,
                stage='reread', wanted=wanted, decoded=reading.image_ok,
            )  # fmt: skip
            for f in again:
                keep(f, reasons[f.stamp])
                if len(keyframes) == len(wanted):
                    break
            if len(keyframes) != len(wanted):
                raise UserError(
                    f'{bag}: changed while read: {len(keyframes)} of {len(wanted)} keyframes found again'
                )
        else:
            selection = {'method': 'streaming'}
            selector = KeyframeSelector(fs.keyframes)
            held: _Frame | None = None  # a blurred frame decided with the next one
            for f in frames:
                d = selector.decide(f.stamp, f.t_wc, blur_px(f.rgb), scene_depth)
                if d.previous is not None and held is not None:
                    decisions[d.previous.reason] += 1
                    if d.previous.keep and keep(held, d.previous.reason):
                        stopped = True
                        break
                held = f if d.reason == 'held' else None
                if held is None:
                    decisions[d.reason] += 1
                if d.keep and keep(f, d.reason):
                    stopped = True
                    break
            if not stopped and (last := selector.flush()) is not None:
                decisions[last.reason] += 1
    overlap = sum(k.reason in ('overlap', INTERVAL_REASONS['overlap']) for k in keyframes)
    if decisions['blurred'] or overlap:
        LOG.info(
            'blur: %d frames dropped as blurred (blur_px > max_blur_px %g px), %d blurred keyframes kept '
            'for overlap (overlap_gap %g)',
            decisions['blurred'], fs.keyframes.max_blur_px, overlap, fs.keyframes.overlap_gap,
        )  # fmt: skip
    counts, bad = reading.counts, reading.bad
    if not keyframes:
        needed = ('image', 'camera_info') if poseless else ('image', 'camera_info', 'pose')
        missing = [k for k in needed if not counts[k]]
        if missing:
            why = f'no {", ".join(missing)} message read'
        elif not counts['frames']:
            why = (
                f'no frame has {" and ".join(needed)} with identical header stamps '
                f'({counts["image"]} images, {counts["camera_info"]} camera_info, {counts["pose"]} poses '
                f'read; bad or incomplete: {dict(bad) or "none"})'
            )
        else:
            why = f'no keyframe among {counts["frames"]} frames ({dict(decisions)})'
        names = ', '.join(str(topics[k]) for k in needed if topics[k] is not None)
        raise UserError(f'{bag}: {why} (topics {names})')
    return Subsampled(
        keyframes, counts, bad, decisions, topics, sfm_why, poseless, reading.fixes, stopped, selection,
        navsat=reading.navsat,
    )  # fmt: skip
