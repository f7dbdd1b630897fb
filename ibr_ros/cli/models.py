# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr models list`` / ``ibr models fetch NAME [--to DIR]``: well-known ONNX models, sha256-verified."""

from __future__ import annotations

import argparse
from pathlib import Path

from ibr_ros.errors import UserError


def _list(args: argparse.Namespace) -> int:
    from ibr_ros.models import SHIPPED_MONO_MODEL
    from ibr_ros.models.registry import MODELS, default_cache_dir

    print(f'shipped: ibr_mono (depth + sky) {SHIPPED_MONO_MODEL}')
    for e in MODELS.values():
        size = f'{e.size_bytes / 1e6:.0f} MB' if e.size_bytes else 'size unknown'
        print(f'{e.name}: preset {e.preset}, {size}, {e.license}\n  {e.url}')
    print(f'cache: {default_cache_dir()}')
    return 0


def _fetch(args: argparse.Namespace) -> int:
    from ibr_ros.cli.progress import progress_bar
    from ibr_ros.models.registry import MODELS, fetch_model

    entry = MODELS.get(args.name)
    if entry is None:
        raise UserError(f'unknown model {args.name!r}; known: {", ".join(sorted(MODELS))}')
    with progress_bar(f'fetch {entry.name}', unit='B', enabled=args.progress) as progress:
        path = fetch_model(
            entry, Path(args.to) if args.to else None, timeout_s=args.timeout, progress=progress
        )
    print(path)
    print(f'use it with MonoModelSpec preset {entry.preset!r}: replace(PRESETS[{entry.preset!r}], path=...)')
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('models', help='list or download well-known ONNX models')
    ms = p.add_subparsers(dest='models_command', metavar='MODELS_COMMAND', required=True)
    ls = ms.add_parser('list', help='the shipped model and the downloadable ones')
    ls.set_defaults(func=_list)
    f = ms.add_parser('fetch', help='download a model from its documented URL and verify its sha256')
    f.add_argument('name', metavar='NAME', help='model name (see `ibr models list`)')
    f.add_argument('--to', metavar='DIR', help='target folder (default: ~/.cache/ibr_ros/models)')
    f.add_argument('--timeout', type=float, default=30.0, help='network timeout in seconds')
    f.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None, help='progress bar')
    f.set_defaults(func=_fetch)
