# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr``: command line entry point.

Each subcommand module defines ``register(subparsers)`` which adds its parser and sets
``func(args) -> int`` as the handler. Errors that are the user's (bad paths, corrupt bags) are
raised as :class:`ibr_ros.errors.UserError` and printed as one line, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ibr_ros import __version__
from ibr_ros.errors import UserError
from ibr_ros.launch_entry import interrupted as _interrupted

SUBCOMMAND_MODULES = (
    'ibr_ros.cli.bag',
    'ibr_ros.cli.register',
    'ibr_ros.cli.eval',
    'ibr_ros.cli.graph',
    'ibr_ros.cli.query',
    'ibr_ros.cli.view',
    'ibr_ros.cli.models',
    'ibr_ros.cli.demo',
    'ibr_ros.cli.process',
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='ibr', description='Image-based rendering for drone captures (ibr_ros).'
    )
    parser.add_argument('--version', action='version', version=f'ibr_ros {__version__}')
    parser.add_argument('-v', '--verbose', action='store_true', help='debug logging')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format='%(levelname)s %(name)s: %(message)s',
    )
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f'ibr {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as exc:  # numba wraps a Ctrl-C in a SystemError
        if not _interrupted(exc):
            raise
        print(f'ibr {args.command}: interrupted, stopped', file=sys.stderr)
        return 0


if __name__ == '__main__':
    sys.exit(main())
