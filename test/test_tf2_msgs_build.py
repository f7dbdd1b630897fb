# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""tools/build_tf2_msgs.sh (run by `make install`): builds vendor/tf2_msgs where tf2_msgs has no wheel,
so that rclpy publishes TFMessage; a no-op where tf2_msgs is importable."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

CHECK = """
import numpy as np
from rclpy.serialization import serialize_message
import msg_utils
from ibr_ros.bag.typestore import TYPESTORE
from tf2_msgs.msg import TFMessage
t = np.eye(4); t[:3, 3] = (1.0, 2.0, 3.0)
tf = [(7, 'map', 'camera_optical_frame', t)]
ours = serialize_message(msg_utils.transforms_to_tf(tf))
bag = TYPESTORE.serialize_cdr(msg_utils.transforms_to_tf(tf, flavor='rosbags'), 'tf2_msgs/msg/TFMessage')
T = 'tf2_msgs/msg/TFMessage'
assert TYPESTORE.deserialize_cdr(ours, T) == TYPESTORE.deserialize_cdr(bytes(bag), T)
print('ok', TFMessage.__module__)
"""


def test_build_tf2_msgs_makes_tfmessage_publishable(repo, tmp_path):
    venv = Path(sys.prefix)
    prefix = tmp_path / 'prefix'
    run = subprocess.run(
        ['sh', str(repo / 'tools' / 'build_tf2_msgs.sh'), str(venv), str(prefix)],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    env = dict(os.environ)
    if 'importable already' in run.stdout:  # a ROS 2 install, or a venv `make install` built it into
        assert not prefix.exists()
    else:
        assert 'installed into' in run.stdout
        site = next(prefix.glob('lib/python3*/site-packages'))
        env['PYTHONPATH'] = os.pathsep.join([str(site), str(repo), env.get('PYTHONPATH', '')])
        env['LD_LIBRARY_PATH'] = os.pathsep.join([str(prefix / 'lib'), env.get('LD_LIBRARY_PATH', '')])
    env['PYTHONPATH'] = os.pathsep.join([str(repo), env.get('PYTHONPATH', '')])
    check = subprocess.run(
        [sys.executable, '-c', CHECK], capture_output=True, text=True, env=env, timeout=120
    )
    assert check.returncode == 0, check.stderr
    assert check.stdout.startswith('ok tf2_msgs.msg')
