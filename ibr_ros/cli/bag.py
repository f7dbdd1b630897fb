# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag ...``: bag subcommands, one module each (``ibr_ros.cli.bag_*``)."""

from __future__ import annotations

import argparse
import importlib

BAG_SUBCOMMANDS = ('ibr_ros.cli.bag_info', 'ibr_ros.cli.bag_synth', 'ibr_ros.cli.bag_from_images')


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('bag', help='inspect, create and convert bags')
    bag_sub = p.add_subparsers(dest='bag_command', metavar='BAG_COMMAND', required=True)
    for name in BAG_SUBCOMMANDS:
        importlib.import_module(name).register(bag_sub)
