# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr graph``: run the node graph as separate processes (for venvs without ``ros2 launch``)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ibr_ros.errors import UserError


def _overrides(items: list[str]) -> dict[str, dict[str, object]]:
    """``NODE.PARAM=VALUE`` items as ``{node: {param: value}}``; VALUE is read as YAML (as ``-p``) and
    checked against the node's parameter table (an integer for a double parameter becomes a double)."""
    import yaml

    from ibr_ros.node_config import NODES, table_of

    out: dict[str, dict[str, object]] = {}
    for item in items:
        key, sep, text = item.partition('=')
        node, dot, param = key.partition('.')
        if not sep or not dot or not node or not param:
            raise UserError(f'--set expects NODE.PARAM=VALUE, got {item!r}')
        try:
            value = yaml.safe_load(text) if text else ''
        except yaml.YAMLError:
            value = text
        if node in NODES:
            value = table_of(node).values({param: value}, where=f'{node}.')[param]
        out.setdefault(node, {})[param] = value
    return out


def build_specs(args: argparse.Namespace) -> list:
    """The node processes of the graph for these command line options."""
    from ibr_ros.graph import NodeSpec

    sets = _overrides(args.set)
    specs = []
    if not args.no_player:
        if not args.bag:
            raise UserError('--bag is required (or --no-player to feed the graph from live topics)')
        if not Path(args.bag).exists():
            raise UserError(f'{args.bag}: no such bag')
        from ibr_ros.graph import wait_for_subsampler

        subsampler = sets.get('frame_subsampler', {})
        params = {
            'bag': str(Path(args.bag).resolve()),
            'rate': args.rate,
            'loop': args.loop,
            # Playback starts once the frame_subsampler listens: nothing of the flight is lost.
            **wait_for_subsampler(
                args.bag,
                str(subsampler.get('image_transport', 'auto')),
                str(subsampler.get('pose_source', 'auto')),
            ),
        }
        specs.append(NodeSpec('bag_player', {**params, **sets.pop('bag_player', {})}))
    specs.append(NodeSpec('frame_subsampler', sets.pop('frame_subsampler', {})))
    refiner = sets.pop('depth_refiner', {})
    for i in range(args.refiners):
        shard = {'worker_index': i, 'num_workers': args.refiners} if args.refiners > 1 else {}
        name = f'depth_refiner_{i}' if args.refiners > 1 else None
        specs.append(NodeSpec('depth_refiner', {**shard, **refiner}, node_name=name))
    specs.append(NodeSpec('view_renderer', sets.pop('view_renderer', {})))
    specs.append(NodeSpec('scene_viz', sets.pop('scene_viz', {})))  # the model for RViz / Foxglove
    if sets:
        raise UserError(f'--set names unknown nodes: {", ".join(sorted(sets))}')
    return specs


def run(args: argparse.Namespace) -> int:
    from ibr_ros.graph import Graph
    from ibr_ros.launch_entry import sigterm_as_interrupt

    sigterm_as_interrupt()  # SIGTERM stops the nodes as Ctrl-C does

    if args.refiners < 1:
        raise UserError(f'--refiners must be >= 1, got {args.refiners}')
    graph = Graph(build_specs(args), log_dir=Path(args.log_dir) if args.log_dir else None)
    with graph:
        print(f'ibr graph: started {", ".join(graph.procs)}; Ctrl-C stops them', flush=True)
        try:
            deadline = time.monotonic() + args.duration if args.duration else None
            while deadline is None or time.monotonic() < deadline:
                status = graph.poll()
                died = {n: rc for n, rc in status.items() if rc not in (None, 0)}
                if died:
                    print(f'ibr graph: node(s) failed: {died}; stopping', flush=True)
                    return 1
                if args.exit_when_done and status.get('bag_player') == 0:
                    time.sleep(args.linger)
                    break
                time.sleep(0.2)
        except KeyboardInterrupt:
            why = 'interrupted; '
        else:
            why = ''
    print(f'ibr graph: {why}stopped ({graph.poll()})', flush=True)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('graph', help='start every node as a separate process (replay a bag through them)')
    p.add_argument('--bag', help='bag to replay with bag_player')
    p.add_argument('--no-player', action='store_true', help='no bag_player: use live topics')
    p.add_argument('--rate', type=float, default=1.0, help='replay rate (0 = as fast as possible)')
    p.add_argument('--loop', action='store_true', help='replay the bag in a loop')
    p.add_argument('--refiners', type=int, default=1, help='number of sharded depth_refiner processes')
    p.add_argument(
        '--set', action='append', default=[], metavar='NODE.PARAM=VALUE', help='parameter override'
    )
    p.add_argument('--log-dir', help='write each node log to LOG_DIR/<node>.log (default: the terminal)')
    p.add_argument('--duration', type=float, default=0.0, help='stop after this many seconds (0 = run on)')
    p.add_argument('--exit-when-done', action='store_true', help='stop once the bag has been replayed')
    p.add_argument('--linger', type=float, default=0.0, help='with --exit-when-done: seconds to wait first')
    p.set_defaults(func=run)
