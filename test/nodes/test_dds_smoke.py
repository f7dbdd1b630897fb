# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""An Image published by one process arrives bit-exact in another over DDS."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import pytest
from dds_peer import make_array

pytestmark = pytest.mark.dds


def test_image_crosses_processes_bit_exact(repo, ros_env):
    peer = str(repo / 'test' / 'dds_peer.py')
    sub = subprocess.Popen(
        [sys.executable, peer, 'sub'], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert sub.stdout.readline().strip() == 'READY'
        pub = subprocess.run(
            [sys.executable, peer, 'pub', '7'], env=ros_env, capture_output=True, text=True, timeout=60
        )
        out, err = sub.communicate(timeout=60)
    finally:
        sub.kill()
    assert pub.returncode == 0, pub.stdout + pub.stderr
    assert sub.returncode == 0, out + err
    expected = hashlib.sha256(make_array(7).tobytes()).hexdigest()
    assert f'RECEIVED {expected} 120 160 rgb8' in out
