# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""What viewers are shown of the keyframe model, kept as keyframes arrive (live) or are written
(``ibr process``): poses, frustums, TF frames and point clouds."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ibr_ros.core.geometry.camera import PinholeCamera
from ibr_ros.core.geometry.transforms import validate_pose
from ibr_ros.core.viz.cloud import CloudConfig, grid, keyframe_points
from ibr_ros.core.viz.frames import FrameNames, camera_transforms, keyframe_frame
from ibr_ros.core.viz.frustum import auto_frustum_depth, frustum_segments, known_median

__all__ = ['KEYFRAME_RGBA', 'NOVEL_VIEW_RGBA', 'VizConfig', 'VizKeyframe', 'VizModel']

#: Frustum colours (RGBA in [0, 1]): keyframes light blue, the novel view orange.
KEYFRAME_RGBA = (0.2, 0.6, 1.0, 1.0)
NOVEL_VIEW_RGBA = (1.0, 0.5, 0.0, 1.0)


@dataclass(frozen=True)
class VizConfig:
    """``cloud``: which pixels become points; ``frames``: TF names; ``frustum_depth_m``: where the
    frustums are cut (metres), 0 = 0.15 x the median refined depth (1 m before any depth)."""

    cloud: CloudConfig = field(default_factory=CloudConfig)
    frames: FrameNames = field(default_factory=FrameNames)
    frustum_depth_m: float = 0.0


@dataclass
class VizKeyframe:
    """One keyframe as far as it arrived; image data kept only on the cloud's stride grid."""

    stamp: int
    marker_id: int
    t_wc: NDArray[np.float64] | None = None
    camera: PinholeCamera | None = None
    rgb: NDArray[np.generic] | None = None  # grid
    depth: NDArray[np.generic] | None = None  # grid, metres
    confidence: NDArray[np.generic] | None = None  # grid
    median_depth: float | None = None


class VizModel:
    """The keyframes (by stamp, in arrival order) in one world frame.

    :meth:`put` takes one field of one keyframe; the products are then read: :meth:`poses`,
    :meth:`frustums`, :meth:`static_transforms` and :meth:`points` of a keyframe (once it has a
    pose, a camera, an image and a depth). Marker ids are given in arrival order, never reused.
    """

    def __init__(self, config: VizConfig | None = None) -> None:
        self.config = config or VizConfig()
        self.keyframes: dict[int, VizKeyframe] = {}
        self.world = ''
        self.novel_view: tuple[PinholeCamera, NDArray[np.float64]] | None = None

    def _get(self, stamp: int) -> VizKeyframe:
        kf = self.keyframes.get(stamp)
        if kf is None:
            kf = self.keyframes[stamp] = VizKeyframe(stamp, len(self.keyframes))
        return kf

    def put_pose(self, stamp: int, t_wc: ArrayLike, world: str) -> bool:
        """Keyframe ``stamp``'s camera-to-world pose (4x4) in frame ``world``; whether it changed.

        Raises:
            ValueError: Not a rigid pose, or another world frame than the model's.

        """
        pose = validate_pose(t_wc, field='t_wc')
        if self.world and world != self.world:
            raise ValueError(f'keyframe {stamp} ns is in frame {world!r}, the model in {self.world!r}')
        self.world = world
        kf = self._get(stamp)
        changed = kf.t_wc is None or not np.array_equal(kf.t_wc, pose)
        kf.t_wc = pose
        return changed

    def put_camera(self, stamp: int, camera: PinholeCamera) -> bool:
        """Keyframe ``stamp``'s intrinsics; whether they changed."""
        kf = self._get(stamp)
        changed = kf.camera is None or kf.camera != camera
        kf.camera = camera
        return changed

    def put_image(self, stamp: int, rgb: ArrayLike) -> None:
        """Keyframe ``stamp``'s HxWx3 uint8 image (kept on the stride grid only)."""
        self._get(stamp).rgb = grid(rgb, self.config.cloud.stride)

    def put_depth(self, stamp: int, depth: ArrayLike) -> bool:
        """Keyframe ``stamp``'s HxW depth in metres (REP-118); whether it changed."""
        kf = self._get(stamp)
        g = grid(depth, self.config.cloud.stride)
        changed = kf.depth is None or not np.array_equal(kf.depth, g, equal_nan=True)
        kf.depth = g
        kf.median_depth = known_median(g)
        return changed

    def put_confidence(self, stamp: int, confidence: ArrayLike) -> bool:
        """Keyframe ``stamp``'s HxW depth confidence in [0, 1]; whether it changed."""
        kf = self._get(stamp)
        g = grid(confidence, self.config.cloud.stride)
        changed = kf.confidence is None or not np.array_equal(kf.confidence, g)
        kf.confidence = g
        return changed

    def drop(self, stamp: int) -> None:
        """Forget keyframe ``stamp`` (its marker id is not reused)."""
        self.keyframes.pop(stamp, None)

    # -- products -----------------------------------------------------------------------------
    def posed(self) -> list[VizKeyframe]:
        """The keyframes with a pose, in arrival order."""
        return [k for k in self.keyframes.values() if k.t_wc is not None]

    def poses(self) -> list[NDArray[np.float64]]:
        """Camera-to-world poses of the posed keyframes, in arrival order."""
        return [k.t_wc for k in self.posed() if k.t_wc is not None]

    def frustum_depth(self) -> float:
        """Where frustums are cut (metres): the configured depth or the automatic one."""
        if self.config.frustum_depth_m > 0:
            return self.config.frustum_depth_m
        return auto_frustum_depth(k.median_depth for k in self.keyframes.values() if k.median_depth)

    def frustums(self) -> list[tuple[int, NDArray[np.float64]]]:
        """``(marker id, (9, 2, 3) world segments)`` of every keyframe with a pose and a camera."""
        depth = self.frustum_depth()
        return [
            (k.marker_id, frustum_segments(k.camera, k.t_wc, depth))
            for k in self.posed()
            if k.camera is not None and k.t_wc is not None
        ]

    def static_transforms(self) -> list[tuple[int, str, str, NDArray[np.float64]]]:
        """``(stamp, parent, child, T)``: the world -> keyframe optical frame of every posed keyframe."""
        prefix = self.config.frames.keyframe_prefix
        return [
            (k.stamp, self.world, keyframe_frame(prefix, k.stamp), k.t_wc)
            for k in self.posed()
            if k.t_wc is not None
        ]

    def camera_transforms(
        self, t_wc: ArrayLike, world: str = ''
    ) -> list[tuple[str, str, NDArray[np.float64]]]:
        """The live camera at pose ``t_wc`` in ``world`` ('' = the model's, else ``map``) as TF
        (``(parent, child, T)``: world -> body -> optical, :func:`camera_transforms`)."""
        names = self.config.frames
        return camera_transforms(t_wc, world or self.world or 'map', names.camera, names.body)

    def set_novel_view(self, camera: PinholeCamera, t_wc: ArrayLike) -> None:
        """The latest answered novel view: its camera and camera-to-world pose (in the model's frame)."""
        self.novel_view = (camera, validate_pose(t_wc, field='t_wc'))

    def line_width(self) -> float:
        """Frustum line width (metres): 2 % of the frustum depth."""
        return 0.02 * self.frustum_depth()

    def frustum_lines(self) -> list[tuple[str, int, NDArray[np.float64], tuple[float, float, float, float]]]:
        """``(namespace, id, (9, 2, 3) segments, RGBA)`` of every frustum to draw: the keyframes
        (``keyframes``, :data:`KEYFRAME_RGBA`) and the latest novel view (``novel_view``, id 0,
        :data:`NOVEL_VIEW_RGBA`)."""
        out = [('keyframes', i, seg, KEYFRAME_RGBA) for i, seg in self.frustums()]
        if self.novel_view is not None:
            camera, t_wc = self.novel_view
            out.append(
                ('novel_view', 0, frustum_segments(camera, t_wc, self.frustum_depth()), NOVEL_VIEW_RGBA)
            )
        return out

    def points(self, stamp: int) -> tuple[NDArray[np.float32], NDArray[np.uint8]] | None:
        """World points and colours of keyframe ``stamp`` (:func:`keyframe_points`), or None while
        its pose, camera, image or depth is missing."""
        k = self.keyframes.get(stamp)
        if k is None or k.t_wc is None or k.camera is None or k.rgb is None or k.depth is None:
            return None
        return keyframe_points(k.depth, k.rgb, k.camera, k.t_wc, k.confidence, self.config.cloud)
