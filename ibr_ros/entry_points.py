# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Executables of the package: one table read by setup.py and by the ``lib/ibr_ros`` launchers.

Kept free of imports so that setup.py can read it without the package's dependencies.
"""

CONSOLE_SCRIPTS: dict[str, str] = {
    'ibr': 'ibr_ros.cli.main:main',
    'frame_subsampler': 'ibr_ros.nodes.frame_subsampler:main',
    'bag_player': 'ibr_ros.nodes.bag_player:main',
    'depth_refiner': 'ibr_ros.nodes.depth_refiner:main',
    'view_renderer': 'ibr_ros.nodes.view_renderer:main',
    'scene_viz': 'ibr_ros.nodes.scene_viz:main',
    'web_viewer': 'ibr_ros.nodes.web_viewer:main',
}
