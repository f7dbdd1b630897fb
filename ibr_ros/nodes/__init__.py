# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Thin rclpy nodes: convert messages with msg_utils, call ibr_ros.core, publish."""
