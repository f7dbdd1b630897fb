# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag info PATH [PATH...] [--json]``: summarise bags."""

from __future__ import annotations

import argparse
import json
import sys

from ibr_ros.errors import BagError


def run(args: argparse.Namespace) -> int:
    """Print each bag's summary; an unreadable bag is one error line on stderr and exit status 2."""
    from ibr_ros.bag.info import bag_info, format_bag_info

    infos: list[object] = []
    failed = False
    for path in args.paths:
        try:
            info = bag_info(path)
        except BagError as exc:
            print(f'ibr bag info: error: {exc}', file=sys.stderr)
            failed = True
            continue
        if args.json:
            infos.append(info.to_dict())
        else:
            if infos:
                print()
            print(format_bag_info(info))
            infos.append(info)
    if args.json and infos:
        print(json.dumps(infos if len(args.paths) > 1 else infos[0], indent=2))
    return 2 if failed else 0


def register(bag_sub: argparse._SubParsersAction) -> None:
    p = bag_sub.add_parser('info', help='summarise bags: storage, time span, topics, rates, image sizes')
    p.add_argument('paths', nargs='+', metavar='PATH', help='rosbag2 directory, .mcap, .db3 or ROS 1 .bag')
    p.add_argument('--json', action='store_true', help='print JSON (a list when several paths are given)')
    p.set_defaults(func=run)
