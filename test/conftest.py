# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Shared test set-up: DDS isolation and paths.

Every test run gets its own ROS_DOMAIN_ID and localhost-only discovery, so that parallel runs on
one machine never see each other's nodes: the run holds a UDP port of its domain's range that DDS does
not use, and a second run (whose pid may well be the same, in a fresh container) takes the next free
domain. Nodes a test made with ``rclpy.create_node`` are destroyed after it, failed or not.

numba caches compiled kernels per source file and does not notice a change in another file whose
function a kernel calls or inlines (``core/render`` kernels call ``projection`` and ``warp``): the
tests (and the node processes they start) use a cache folder named after a hash of every source file
of ``ibr_ros``, so an edited checkout never runs a stale kernel.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _numba_cache_dir() -> Path:
    """``.numba_cache/<hash of the ibr_ros sources>``; caches of other source states are removed."""
    digest = hashlib.sha256()
    for path in sorted((REPO / 'ibr_ros').rglob('*.py')):
        digest.update(path.relative_to(REPO).as_posix().encode() + b'\0' + path.read_bytes())
    root = REPO / '.numba_cache'
    here = root / digest.hexdigest()[:16]
    if root.is_dir():
        for old in root.iterdir():
            if old != here:
                shutil.rmtree(old, ignore_errors=True)
    return here


os.environ.setdefault('NUMBA_CACHE_DIR', str(_numba_cache_dir()))  # before anything imports numba

import pytest  # noqa: E402
import rclpy  # noqa: E402

from ibr_ros.graph import claim_domain  # noqa: E402

if 'IBR_TEST_DOMAIN_ID' in os.environ:
    DOMAIN_ID = int(os.environ['IBR_TEST_DOMAIN_ID'])
else:
    DOMAIN_ID, _DOMAIN_LOCK = claim_domain(1 + os.getpid() % 100)

os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


@pytest.fixture(autouse=True)
def _destroy_test_nodes(monkeypatch) -> Iterator[None]:
    """Destroy the nodes the test made with ``rclpy.create_node`` once it is over.

    A failed test's frames stay referenced (``sys.last_traceback``); a node left alive would go on
    serving its transient-local history to the next tests' subscriptions.
    """
    made = []
    create = rclpy.create_node

    def tracked(*args, **kwargs):
        node = create(*args, **kwargs)
        made.append(node)
        return node

    monkeypatch.setattr(rclpy, 'create_node', tracked)
    yield
    for node in made:
        node.destroy_node()  # a no-op for a node the test destroyed itself


@pytest.fixture(scope='session')
def repo() -> Path:
    return REPO


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for child processes that join this run's isolated DDS domain."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join([str(REPO), env.get('PYTHONPATH', '')]).rstrip(os.pathsep)
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture(scope='session')
def python() -> str:
    return sys.executable


@pytest.fixture(scope='session')
def synth_bags(tmp_path_factory) -> dict[str, Path]:
    """The shipped synthetic flight and two small generated ones (seed 1 lawnmower, seed 2 forward).

    Generated once per test run and shared by the depth and rephotography evaluations.
    """
    from ibr_ros.cli.main import main

    root = tmp_path_factory.mktemp('synth_bags')
    bags = {'shipped': REPO / 'bags' / 'synth_orbit_s0'}
    for seed, kind in ((1, 'lawnmower'), (2, 'forward')):
        out = root / f'seed{seed}'
        args = ['bag', 'synth', '--seed', str(seed), '--trajectory', kind, '--duration', '6', '--fps', '2']
        assert main([*args, '--size', '480x270', '--depth-every', '100', '--out', str(out)]) == 0
        bags[f'seed{seed}'] = out
    return bags
