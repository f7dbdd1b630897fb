# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""File formats outside ROS: photo metadata; files written whole or not at all (:mod:`.atomic`)."""
