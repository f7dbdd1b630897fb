# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The web_viewer's parameter table and the configuration built from it."""

from __future__ import annotations

from dataclasses import dataclass

from ibr_ros.errors import UserError
from ibr_ros.node_config.table import (
    DIAGNOSTICS_PERIOD,
    DIAGNOSTICS_TOPIC,
    Diagnostics,
    Param,
    ParamTable,
    Topic,
    Values,
)

__all__ = ['WEB_VIEWER', 'WebViewerConfig']


@dataclass(frozen=True)
class WebViewerConfig:
    """What the web_viewer node runs with (see :data:`WEB_VIEWER` for each field's meaning and units)."""

    host: str
    port: int
    url_file: str
    jpeg_quality: int
    query_frame: str
    speed_spacings_per_s: float
    default_speed_mps: float
    fast_factor: float
    turn_rate_deg_s: float
    drag_deg_per_px: float
    up_axis: tuple[float, float, float]
    map_px: int
    reply_timeout_s: float
    save_dir: str


def _build(v: Values) -> WebViewerConfig:
    up = v.numbers('up_axis')
    if len(up) != 3 or sum(x * x for x in up) < 1e-12:
        raise UserError(f'parameter up_axis must be a non-zero [x, y, z], got {up!r}')
    return WebViewerConfig(
        host=v.text('host'),
        port=v.integer('port'),
        url_file=v.text('url_file'),
        jpeg_quality=v.integer('jpeg_quality'),
        query_frame=v.text('query_frame'),
        speed_spacings_per_s=v.number('speed_spacings_per_s'),
        default_speed_mps=v.number('default_speed_mps'),
        fast_factor=v.number('fast_factor'),
        turn_rate_deg_s=v.number('turn_rate_deg_s'),
        drag_deg_per_px=v.number('drag_deg_per_px'),
        up_axis=(up[0], up[1], up[2]),
        map_px=v.integer('map_px'),
        reply_timeout_s=v.number('reply_timeout_s'),
        save_dir=v.text('save_dir'),
    )


WEB_VIEWER: ParamTable[WebViewerConfig] = ParamTable(
    node='web_viewer',
    summary=(
        'Serves a local web page to fly through the model: keys (WASD, QE, arrows) and mouse drag move '
        'the camera, each pose goes as a `novel_view/query` and the view is shown as it arrives, with a '
        'top-down keyframe map (click one to jump there), a views/s and latency readout and a save '
        'button. One query in flight per page: poses made meanwhile are superseded by the newest '
        '(counted), so the page never queues stale views.'
    ),
    params=(
        Param('host', '127.0.0.1', 'address to serve on (127.0.0.1: this machine only)'),
        Param('port', 8080, 'TCP port to serve on; 0 = any free port', (0, 65535)),
        Param('url_file', '', 'write the URL served to this file once listening (empty: no file)'),
        Param('jpeg_quality', 85, 'JPEG quality of the views sent to the page', (1, 100)),
        Param('query_frame', '', "header.frame_id of the queries; empty: the keyframe poses' frame"),
        Param(
            'speed_spacings_per_s',
            2.0,
            'flying speed in keyframe spacings per second (median distance of a keyframe to its nearest)',
            (0.01, 1e3),
        ),
        Param('default_speed_mps', 1.0, 'flying speed before two keyframes are known (m/s)', (0.001, 1e4)),
        Param('fast_factor', 4.0, 'speed factor while Shift is held', (1.0, 100.0)),
        Param('turn_rate_deg_s', 60.0, 'turn rate of the arrow keys (deg/s)', (1.0, 720.0)),
        Param('drag_deg_per_px', 0.2, 'turn per pixel of mouse drag (deg)', (0.001, 10.0)),
        Param(
            'up_axis',
            [0.0, 0.0, 1.0],
            "the map frame's up direction: yaw turns about it, the map looks down it (ENU: z)",
        ),
        Param('map_px', 256, 'size of the square top-down keyframe map (px)', (64, 2048)),
        Param(
            'reply_timeout_s',
            5.0,
            'a query unanswered this long (no novel_view/status: renderer gone) is given up, counted '
            'and logged, and the newest pose sent; 0 = wait forever',
            (0.0, 1e6),
        ),
        Param('save_dir', 'ibr_views', 'folder where the save button writes view_<stamp>.png and .json'),
        DIAGNOSTICS_PERIOD,
    ),
    build=_build,
    subscribes=(
        Topic(
            'keyframes/pose',
            'geometry_msgs/PoseStamped',
            'keyframe poses: the map, the start pose and the flying speed',
            'reliable, transient local',
        ),
        Topic('novel_view/image', 'sensor_msgs/Image', 'the views rendered for this viewer', 'reliable'),
        Topic(
            'novel_view/status',
            'diagnostic_msgs/DiagnosticArray',
            'one per query: answered or refused (shown on the page), rendered fraction, render time',
            'reliable',
        ),
    ),
    publishes=(
        Topic(
            'novel_view/query',
            'geometry_msgs/PoseStamped',
            'camera-to-world optical-frame pose of the view wanted, a unique stamp per query',
            'reliable',
        ),
        DIAGNOSTICS_TOPIC,
    ),
    diagnostics=Diagnostics(
        inputs=('pose', 'image', 'status'),
        outputs=('query', 'view'),
        latency="from a page's query published to its view received from the renderer (the round trip)",
        reasons=(
            ('pose', 'a malformed keyframe pose'),
            ('frame', "a keyframe pose in another frame than the first ones'"),
            ('image', 'a malformed novel view of this viewer'),
            ('jpeg', 'a view that could not be JPEG-encoded'),
            ('status', 'a malformed novel_view/status'),
            ('origin', 'a WebSocket from another site (refused, 403)'),
            ('page_input', 'a malformed message from the page'),
            ('save', 'a view that could not be saved'),
        ),
        queues=(('in_flight', 'queries awaiting their reply (at most one per page; bound: the pages)'),),
        model=(
            ('keyframes', 'keyframe poses on the map'),
            ('pages', 'pages connected'),
            ('lost', 'queries given up after `reply_timeout_s` without a reply'),
        ),
    ),
)
