# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The installed package is what `ros2 run` and `ros2 pkg` expect.

ros2cli has no wheels here, so these tests do what ``ros2 run ibr_ros <exe>`` does: find the
package prefix in the ament index (AMENT_PREFIX_PATH) and run the executable file in
``<prefix>/lib/ibr_ros/``.
"""

from __future__ import annotations

import os
import subprocess
import xml.etree.ElementTree as ET

import pytest
from ament_index_python import packages as ament

from ibr_ros.entry_points import CONSOLE_SCRIPTS

pytestmark = pytest.mark.e2e


def _prefix() -> str:
    if not os.environ.get('AMENT_PREFIX_PATH'):
        pytest.fail('AMENT_PREFIX_PATH is not set: run the tests through `make test`')
    return ament.get_package_prefix('ibr_ros')


def test_package_xml_is_format3_ament_python(repo):
    root = ET.parse(repo / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'ibr_ros'
    assert root.find('export/build_type').text == 'ament_python'
    deps = {e.text for e in root.findall('exec_depend')}
    for dep in (
        'rclpy',
        'sensor_msgs',
        'geometry_msgs',
        'std_msgs',
        'builtin_interfaces',
        'nav_msgs',
        'rosgraph_msgs',
    ):
        assert dep in deps
    assert (repo / 'resource' / 'ibr_ros').is_file()
    assert 'script_dir=$base/lib/ibr_ros' in (repo / 'setup.cfg').read_text()


def test_ament_index_lists_package():
    prefix = _prefix()
    share = ament.get_package_share_directory('ibr_ros')
    assert os.path.isfile(os.path.join(share, 'package.xml'))
    assert os.path.isdir(os.path.join(prefix, 'lib', 'ibr_ros'))


@pytest.mark.parametrize('name', sorted(CONSOLE_SCRIPTS))
def test_ros2_run_executable_exists(name):
    path = os.path.join(_prefix(), 'lib', 'ibr_ros', name)
    assert os.path.isfile(path), path
    assert os.access(path, os.X_OK), path


def test_ros2_run_ibr_version(tmp_path):
    exe = os.path.join(_prefix(), 'lib', 'ibr_ros', 'ibr')
    # Run from an unrelated folder so that the installed package, not the checkout, is imported.
    out = subprocess.run([exe, '--version'], capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('ibr_ros ')


def test_installed_package_finds_its_params_files_without_the_ament_index(tmp_path):
    """A pip-installed venv used without AMENT_PREFIX_PATH: the config comes from <prefix>/share."""
    python = os.path.join(_prefix(), 'bin', 'python')  # the venv's interpreter, as the launchers use
    if not os.path.exists(python):  # a colcon install prefix: no interpreter of its own
        pytest.skip(f'{_prefix()} is a colcon install prefix, not a venv (no bin/python)')
    env = {k: v for k, v in os.environ.items() if k != 'AMENT_PREFIX_PATH'}
    code = 'import sys; from ibr_ros.graph import config_dir; print(config_dir(), sys.prefix)'
    out = subprocess.run(
        [python, '-c', code], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60
    )
    assert out.returncode == 0, out.stderr
    config, prefix = out.stdout.split()
    assert config == os.path.join(prefix, 'share', 'ibr_ros', 'config')
    assert os.path.isfile(os.path.join(config, 'view_renderer.yaml'))
