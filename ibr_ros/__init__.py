# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""ibr_ros: image-based rendering of drone captures (Liu et al. 2020) as a ROS 2 node graph."""

__version__ = '0.1.0'
