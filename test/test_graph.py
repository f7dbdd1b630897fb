# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr graph`` process specs and the launch file (checked against stand-in launch modules).

ros2launch has no wheels here, so the launch file is executed with minimal fake ``launch`` and
``launch_ros`` modules that record what it would start.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import types

import pytest

from ibr_ros.cli.graph import build_specs
from ibr_ros.errors import UserError
from ibr_ros.graph import NodeSpec, node_command


def _args(**kw) -> argparse.Namespace:
    base = {'bag': None, 'no_player': False, 'rate': 1.0, 'loop': False, 'refiners': 1, 'set': []}
    return argparse.Namespace(**{**base, **kw})


def test_specs_with_sharded_refiners(repo):
    specs = build_specs(
        _args(bag=str(repo / 'bags' / 'synth_orbit_s0'), refiners=2, set=['view_renderer.width=320'])
    )
    assert [s.label for s in specs] == [
        'bag_player', 'frame_subsampler', 'depth_refiner_0', 'depth_refiner_1', 'view_renderer', 'scene_viz'
    ]  # fmt: skip
    assert specs[2].params == {'worker_index': 0, 'num_workers': 2}
    player = specs[0].params  # playback waits for the frame_subsampler, however long that takes
    assert (player['wait_for_subscribers'], player['wait_timeout_s']) == (1, 0.0)
    assert player['wait_topics'] == ['/camera/image_raw/compressed', '/camera/camera_info', '/camera/pose']
    assert specs[4].params == {'width': 320}  # typed by the view_renderer's table
    cmd = node_command(specs[3], config=repo / 'config', python='python3')
    # -P: the installed package, never a checkout in the working directory.
    assert cmd[:6] == ['python3', '-P', '-m', 'ibr_ros.launch_entry', 'depth_refiner', '--ros-args']
    assert cmd[-2:] == ['-r', '__node:=depth_refiner_1']
    assert '-p' in cmd
    assert 'num_workers:=2' in cmd


def test_bad_graph_options():
    with pytest.raises(UserError, match='--bag is required'):
        build_specs(_args())
    with pytest.raises(UserError, match='no such bag'):
        build_specs(_args(bag='/nonexistent'))
    with pytest.raises(UserError, match='unknown nodes'):
        build_specs(_args(no_player=True, set=['renderer.x=1']))
    with pytest.raises(UserError, match=r'NODE\.PARAM=VALUE'):
        build_specs(_args(no_player=True, set=['oops']))
    assert node_command(NodeSpec('frame_subsampler', {'publish': True}), python='p')[-2:] == [
        '-p', 'publish:=true'
    ]  # fmt: skip


def _fake_launch_modules(monkeypatch, share: str) -> list:
    started: list = []

    class Node:
        def __init__(self, **kw):
            started.append(kw)

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context[self.name]

    class OpaqueFunction:
        def __init__(self, function):
            self.function = function

    launch = types.ModuleType('launch')
    launch.LaunchDescription = lambda actions: actions
    actions = types.ModuleType('launch.actions')
    actions.DeclareLaunchArgument = lambda name, default_value='', description='': (name, default_value)
    actions.OpaqueFunction = OpaqueFunction
    subs = types.ModuleType('launch.substitutions')
    subs.LaunchConfiguration = LaunchConfiguration
    launch_ros = types.ModuleType('launch_ros')
    ros_actions = types.ModuleType('launch_ros.actions')
    ros_actions.Node = Node
    ament = types.ModuleType('ament_index_python.packages')
    ament.get_package_share_directory = lambda name: share
    for name, mod in {
        'launch': launch, 'launch.actions': actions, 'launch.substitutions': subs,
        'launch_ros': launch_ros, 'launch_ros.actions': ros_actions, 'ament_index_python.packages': ament,
    }.items():  # fmt: skip
        monkeypatch.setitem(sys.modules, name, mod)
    return started


def test_launch_file_starts_the_same_nodes(repo, monkeypatch):
    started = _fake_launch_modules(monkeypatch, '/opt/share/ibr_ros')
    spec = importlib.util.spec_from_file_location('ibr_graph_launch', repo / 'launch' / 'ibr_graph.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    desc = module.generate_launch_description()
    defaults = dict(d for d in desc if isinstance(d, tuple))
    assert defaults['config_dir'] == '/opt/share/ibr_ros/config'
    opaque = desc[-1]
    bag = str(repo / 'bags' / 'synth_orbit_s0')
    context = {**defaults, 'config_dir': str(repo / 'config'), 'bag': bag, 'rate': '2.0', 'refiners': '2'}
    opaque.function(context)
    names = [n['name'] for n in started]
    assert names == [
        'bag_player', 'frame_subsampler', 'depth_refiner_0', 'depth_refiner_1', 'view_renderer', 'scene_viz'
    ]  # fmt: skip
    assert started[0]['parameters'][1] == {
        'bag': bag,
        'rate': 2.0,
        'wait_for_subscribers': 1,
        'wait_timeout_s': 0.0,
        'wait_topics': ['/camera/image_raw/compressed', '/camera/camera_info', '/camera/pose'],
    }
    assert started[1]['parameters'][1] == {
        'image_transport': 'auto',
        'pose_source': 'auto',
        'scene_depth_m': 0.0,
    }
    assert started[3]['parameters'][1] == {
        'max_neighbours': 4, 'scene_depth_m': 0.0, 'worker_index': 1, 'num_workers': 2
    }  # fmt: skip
    assert all(n['package'] == 'ibr_ros' for n in started)


def test_camera_topics_follow_the_subsampler_settings(repo, tmp_path):
    from ibr_ros.graph import camera_topics

    bag = repo / 'bags' / 'synth_orbit_s0'
    assert camera_topics(bag, 'auto', 'none') == ['/camera/image_raw/compressed', '/camera/camera_info']
    with pytest.raises(UserError, match='no /camera/image_raw topic'):
        camera_topics(bag, 'raw')


def test_ibr_process_removes_stale_staging_folders(tmp_path):
    from ibr_ros.jobs.process import _remove_stale_stages

    out = tmp_path / 'o'
    dead, live = tmp_path / '.o.partial-999999999', tmp_path / f'.o.old-{os.getppid()}'
    other = tmp_path / '.other.partial-999999999'
    for p in (dead, live, other):
        p.mkdir()
    _remove_stale_stages(out)
    assert not dead.exists()
    assert live.exists()  # a running process's
    assert other.exists()  # another output's


def test_set_values_are_read_as_yaml_and_checked_against_the_node_table(repo):
    from ibr_ros.graph import node_command

    specs = build_specs(
        _args(
            no_player=True,
            set=['view_renderer.hfov_deg=80', 'view_renderer.frame_id=cam', 'view_renderer.warmup=false'],
        )
    )
    renderer = next(s for s in specs if s.name == 'view_renderer')
    assert renderer.params == {'hfov_deg': 80.0, 'frame_id': 'cam', 'warmup': False}
    assert 'hfov_deg:=80.0' in node_command(renderer)
    quoted = build_specs(_args(no_player=True, set=["view_renderer.frame_id='1'"]))[-2]
    assert quoted.params == {'frame_id': '1'}
    assert "frame_id:='1'" in node_command(quoted)  # read back as the string '1', not the integer 1
    with pytest.raises(UserError, match=r'parameter view_renderer\.width must be an integer'):
        build_specs(_args(no_player=True, set=['view_renderer.width=wide']))
    with pytest.raises(UserError, match="'x' is not a parameter of view_renderer"):
        build_specs(_args(no_player=True, set=['view_renderer.x=1']))
