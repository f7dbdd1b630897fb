# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The web viewer's HTTP and WebSocket server (aiohttp, no rclpy) and its page (``static/``: plain
HTML/JS/CSS, nothing fetched from elsewhere)."""

from __future__ import annotations

from ibr_ros.web.server import Reply, ViewerServer, pack_frame, unpack_frame

__all__ = ['Reply', 'ViewerServer', 'pack_frame', 'unpack_frame']
