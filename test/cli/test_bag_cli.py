# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr bag info``: output, JSON, and one-line errors for broken bags."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap_helpers import corrupt_chunk

from ibr_ros.bag import TYPESTORE, BagWriter
from ibr_ros.cli.main import main

T = TYPESTORE.types
SEC = 1_000_000_000
REPO = Path(__file__).resolve().parents[2]


def write_bag(path: Path) -> Path:
    """Ten 4x2 mono8 images at 5 Hz and one NavSatFix."""
    header = T['std_msgs/msg/Header']
    time = T['builtin_interfaces/msg/Time']
    with BagWriter(path) as writer:
        for i in range(10):
            ns = SEC + i * SEC // 5
            img = T['sensor_msgs/msg/Image'](
                header=header(stamp=time(sec=ns // SEC, nanosec=ns % SEC), frame_id='cam'),
                height=2,
                width=4,
                encoding='mono8',
                is_bigendian=0,
                step=4,
                data=np.zeros(8, np.uint8),
            )
            writer.write('/cam/image_raw', img, ns)
        fix = T['sensor_msgs/msg/NavSatFix'](
            header=header(stamp=time(sec=1, nanosec=0), frame_id='gps'),
            status=T['sensor_msgs/msg/NavSatStatus'](status=0, service=1),
            latitude=1.0,
            longitude=2.0,
            altitude=3.0,
            position_covariance=np.zeros(9),
            position_covariance_type=0,
        )
        writer.write('/fix', fix, SEC)
    return path


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A good bag and broken ones: truncated, corrupt, empty, garbage, missing."""
    folder = tmp_path_factory.mktemp('cli')
    good = write_bag(folder / 'good')
    data = (good / 'good_0.mcap').read_bytes()
    (folder / 'truncated.mcap').write_bytes(data[: len(data) - 100])
    (folder / 'corrupt.mcap').write_bytes(corrupt_chunk(data))
    (folder / 'garbage.bag').write_bytes(b'#ROSBAG V1.0\n' + bytes(64))
    with BagWriter(folder / 'empty') as writer:
        writer.add_topic('/a', 'std_msgs/msg/String')
    return {
        'good': good,
        'truncated': folder / 'truncated.mcap',
        'corrupt': folder / 'corrupt.mcap',
        'garbage': folder / 'garbage.bag',
        'empty': folder / 'empty',
        'missing': folder / 'missing',
    }


def test_info_table(bags: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bag', 'info', str(bags['good'])]) == 0
    out = capsys.readouterr().out
    assert 'Storage:   mcap' in out
    assert 'Messages:  11' in out
    assert 'Duration:  1.800 s' in out
    row = next(line.split() for line in out.splitlines() if '/cam/image_raw' in line)
    assert row == ['/cam/image_raw', 'sensor_msgs/msg/Image', '10', '5.00', '4x2', 'mono8']


def test_info_json(bags: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bag', 'info', '--json', str(bags['good'])]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info['storage'] == 'mcap'
    assert info['message_count'] == 11
    topics = {t['name']: t for t in info['topics']}
    assert topics['/cam/image_raw']['image'] == {'width': 4, 'height': 2, 'encoding': 'mono8'}
    assert topics['/fix']['rate_hz'] is None


@pytest.mark.parametrize(
    ('name', 'problem'),
    [
        ('truncated', 'truncated MCAP file (no footer); the recording may have been interrupted'),
        ('corrupt', 'cannot read messages'),
        ('garbage', 'corrupt or unreadable ROS 1 bag'),
        ('empty', 'bag contains no messages'),
        ('missing', 'no such file or directory'),
    ],
)
def test_broken_bag_is_one_line(
    bags: dict[str, Path], capsys: pytest.CaptureFixture[str], name: str, problem: str
) -> None:
    assert main(['bag', 'info', str(bags[name])]) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(f'ibr bag info: error: {bags[name]}: ')
    assert problem in lines[0]


def test_several_paths_report_each(bags: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['bag', 'info', str(bags['good']), str(bags['empty'])]) == 2
    captured = capsys.readouterr()
    assert 'Path:      ' in captured.out
    assert len(captured.err.splitlines()) == 1


def test_subprocess_error_has_no_traceback(bags: dict[str, Path]) -> None:
    result = subprocess.run(
        [sys.executable, '-m', 'ibr_ros.cli.main', 'bag', 'info', str(bags['truncated'])],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == (
        f'ibr bag info: error: {bags["truncated"]}: '
        'truncated MCAP file (no footer); the recording may have been interrupted'
    )
