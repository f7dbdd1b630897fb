"""Shared test set-up: DDS isolation and paths.

Every test run gets its own ROS_DOMAIN_ID (from the pid) and localhost-only discovery, so that
parallel runs on one machine never see each other's nodes.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOMAIN_ID = int(os.environ.get('IBR_TEST_DOMAIN_ID', str(1 + os.getpid() % 100)))

os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


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
