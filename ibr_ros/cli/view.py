# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr view``: fly through the model in a web browser.

Starts the ``web_viewer`` node (a local page; :mod:`ibr_ros.nodes.web_viewer`) and prints its URL.
Live (no ``--bag``): it joins the running graph (this shell's ROS_DOMAIN_ID) and queries its
``view_renderer``. ``--bag OUT/bag`` (an ``ibr process`` output bag): also starts a ``bag_player``
that replays the bag's model (``/keyframes/*``, transient local, kept published until the end) and
a ``view_renderer`` fed from it, in a DDS domain of their own (localhost only). Runs until Ctrl-C
(or SIGTERM), then stops every node it started; exit status 1 when a node failed.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from ibr_ros.errors import UserError

#: The model topics of an output bag (``ibr_ros.jobs.process.output.OUT_TOPICS``) that a renderer needs.
MODEL_TOPICS = ('/keyframes/image', '/keyframes/camera_info', '/keyframes/pose', '/keyframes/depth',
                '/keyframes/depth/confidence')  # fmt: skip


def view_nodes(args: argparse.Namespace, url_file: Path) -> list:
    """The nodes ``ibr view`` starts (:class:`ibr_ros.graph.NodeSpec`)."""
    from ibr_ros.bag import open_bag
    from ibr_ros.graph import NodeSpec

    viewer = NodeSpec('web_viewer', {'host': args.host, 'port': args.port, 'url_file': str(url_file),
                                     'save_dir': str(Path(args.save_dir).resolve())})  # fmt: skip
    if not args.bag:
        return [viewer]
    bag = Path(args.bag)
    with open_bag(bag) as reader:  # UserError when it is no bag
        topics = [t for t in MODEL_TOPICS if t in reader.topics]
    missing = [t for t in MODEL_TOPICS[:4] if t not in topics]
    if missing:
        raise UserError(f'{bag}: no {", ".join(missing)}: not an ibr process output bag')
    player = {'bag': str(bag.resolve()), 'rate': 0.0, 'topics': topics, 'linger_s': -1.0,
              'publish_clock': False, 'wait_for_subscribers': 1, 'wait_timeout_s': 0.0,
              'wait_topics': topics[:4]}  # fmt: skip
    renderer = {'width': args.width, 'height': args.height, 'hfov_deg': args.hfov, 'blend': args.blend}
    return [NodeSpec('view_renderer', renderer), NodeSpec('bag_player', player), viewer]


def run(args: argparse.Namespace) -> int:
    from ibr_ros.graph import Graph, claim_domain
    from ibr_ros.launch_entry import sigterm_as_interrupt

    with tempfile.TemporaryDirectory(prefix='ibr_view_') as tmp:
        url_file = Path(tmp) / 'url'
        nodes = view_nodes(args, url_file)  # a bag without a model: UserError before anything starts
        sigterm_as_interrupt()
        env = dict(os.environ)
        lock = None
        if args.bag:
            domain, lock = claim_domain(1 + os.getpid() % 100)
            env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        graph = Graph(nodes, env=env, log_dir=Path(args.logs) if args.logs else None, grace_s=10.0)
        try:
            graph.start()
            while not url_file.is_file():  # the viewer writes it once it listens
                if graph.wait_for('web_viewer', timeout=0.1) is not None:
                    print(f'ibr view: the web_viewer stopped (exit status {graph.poll()["web_viewer"]})',
                          file=sys.stderr)  # fmt: skip
                    return 1
            url = url_file.read_text().strip()
            where = f'replaying the model of {args.bag}' if args.bag else 'querying the running graph'
            print(f'ibr view: open {url} ({where}; Ctrl-C stops)', flush=True)
            while graph.wait_for('web_viewer', timeout=0.5) is None:  # and watch the others
                if any(rc not in (None, 0) for rc in graph.poll().values()):
                    break
            print(f'ibr view: node(s) stopped: {graph.poll()}', file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print('ibr view: stopping', file=sys.stderr)
            return 0
        finally:
            graph.stop()
            if lock is not None:
                lock.close()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('view', help='fly through the model in a web browser (live graph or an output bag)')
    p.add_argument(
        '--bag', help='an ibr process output bag (OUT/bag): serve its model with a renderer of its own'
    )
    p.add_argument(
        '--host', default='127.0.0.1', help='address to serve on (default 127.0.0.1: this machine)'
    )
    p.add_argument('--port', type=int, default=8080, help='TCP port (default 8080; 0 = any free port)')
    p.add_argument(
        '--width', type=int, default=640, help='--bag: output width of the renderer (px, default 640)'
    )
    p.add_argument('--height', type=int, default=360, help='--bag: output height (px, default 360)')
    p.add_argument('--hfov', type=float, default=0.0, help="--bag: horizontal FOV (deg; 0 = the keyframes')")
    p.add_argument(
        '--blend',
        default='stable',
        choices=('stable', 'ulr', 'soft', 'paper'),
        help="--bag: the renderer's blend (default stable: view weights continuous in the pose, no "
        'flicker when the nearest views change; see `ibr eval path`)',
    )
    p.add_argument('--save-dir', default='ibr_views', help='where the save button writes (default ibr_views)')
    p.add_argument('--logs', help="write the nodes' logs into this folder instead of the terminal")
    p.set_defaults(func=run)
