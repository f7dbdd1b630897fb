# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Flying through the model from a browser (no rclpy): key and mouse input to camera poses
(:class:`Navigator`, REP-103 optical frame: z forward, x right, y down; map frame z up), the flying
speed from the keyframe spacing (:func:`scene_speed`), the top-down keyframe map
(:class:`TopDownMap`) and the newest-request-only gates of one viewer (:class:`NewestOnly`,
:class:`ViewSession`)."""

from __future__ import annotations

from ibr_ros.core.navigation.flight import Motion, NavigationError, Navigator, scene_speed
from ibr_ros.core.navigation.gate import NewestOnly
from ibr_ros.core.navigation.map import MapKeyframe, TopDownMap
from ibr_ros.core.navigation.session import Query, ViewSession

__all__ = [
    'MapKeyframe',
    'Motion',
    'NavigationError',
    'Navigator',
    'NewestOnly',
    'Query',
    'TopDownMap',
    'ViewSession',
    'scene_speed',
]
