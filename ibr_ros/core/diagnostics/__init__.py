# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""A node's diagnostics (``/diagnostics``): input and output rates, output latency, rejections by
reason, queue depths and model size, with their levels (no rclpy)."""

from __future__ import annotations

from ibr_ros.core.diagnostics.tracker import (
    AREAS,
    FATAL_REASONS,
    LATENCY_SAMPLES,
    RATE_WINDOW_S,
    AreaStatus,
    LatencyStats,
    LatencyTracker,
    NodeDiagnostics,
    Queue,
    RateMeter,
)

__all__ = [
    'AREAS',
    'FATAL_REASONS',
    'LATENCY_SAMPLES',
    'RATE_WINDOW_S',
    'AreaStatus',
    'LatencyStats',
    'LatencyTracker',
    'NodeDiagnostics',
    'Queue',
    'RateMeter',
]
