# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Pure algorithms on numpy arrays: no rclpy, no message types."""
