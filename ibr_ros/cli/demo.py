"""``ibr demo``: the main job on the embedded default bags.

Until the node graph lands this prints ``ibr bag info`` for every bag under ``bags/``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ibr_ros.errors import UserError


def default_bags_dir() -> Path:
    """The repository's ``bags/`` folder (the demo runs from a source checkout)."""
    return Path.cwd() / 'bags'


def run(args: argparse.Namespace) -> int:
    from ibr_ros.bag.info import bag_info, format_bag_info
    from ibr_ros.bag.reader import find_bags

    bags = find_bags(Path(args.bags))
    if not bags:
        raise UserError(f'no bags found under {args.bags}')
    for path in bags:
        print(format_bag_info(bag_info(path)))
        print()
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('demo', help='run the main job on the default bags')
    p.add_argument('--bags', default=str(default_bags_dir()), help='folder of bags (default: ./bags)')
    p.set_defaults(func=run)
