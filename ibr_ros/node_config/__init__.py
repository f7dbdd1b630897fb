"""Node parameter tables: one per node, shared by the rclpy nodes, ``ibr process``, ``config/*.yaml``
and the README's node reference (no rclpy).

Errors are :class:`~ibr_ros.errors.UserError` naming the parameter and its value, e.g. ``parameter
sfm_mode must be 'auto', 'always' or 'off', got 'sometimes'``.
"""

from __future__ import annotations

from ibr_ros.node_config.depth_refiner import DEPTH_REFINER, DepthRefinerConfig
from ibr_ros.node_config.table import Param, ParamTable, Topic, Value
from ibr_ros.node_config.view_renderer import INTRINSICS, VIEW_RENDERER, ViewRendererConfig, render_config

__all__ = [
    'DEPTH_REFINER',
    'INTRINSICS',
    'TABLES',
    'VIEW_RENDERER',
    'DepthRefinerConfig',
    'Param',
    'ParamTable',
    'Topic',
    'Value',
    'ViewRendererConfig',
    'render_config',
]

#: Every node's table, by node name, in the order data flows through the graph.
TABLES: dict[str, ParamTable[object]] = {t.node: t for t in (DEPTH_REFINER, VIEW_RENDERER)}
