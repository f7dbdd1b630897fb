# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr demo``: the main job on the embedded default bag (see :mod:`ibr_ros.jobs.demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    from ibr_ros.jobs.demo import run_demo

    summary = run_demo(Path(args.bag), Path(args.out), n_queries=args.queries, rate=args.rate,
                       timeout_s=args.timeout)  # fmt: skip
    print((Path(args.out) / 'summary.md').read_text())
    return 0 if summary['answered'] and summary['refined'] == summary['keyframes'] else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('demo', help='run the node graph on the default synthetic bag and query novel views')
    p.add_argument(
        '--bag', default='bags/synth_orbit_s0', help='synthetic bag (default: bags/synth_orbit_s0)'
    )
    p.add_argument('--out', default='out', help='output folder (default: out)')
    p.add_argument('--queries', type=int, default=8, help='novel views along the path between keyframes')
    p.add_argument('--rate', type=float, default=1.0, help='replay rate (1 = real time, 0 = fastest)')
    p.add_argument('--timeout', type=float, default=900.0, help='give up after this many seconds')
    p.set_defaults(func=run)
