# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The shipped viewer configurations (config/foxglove_layout.json, config/ibr.rviz) parse, name only
topics of the graph and are installed with the package."""

from __future__ import annotations

import json

import yaml

from ibr_ros.jobs.images_to_bag import TOPICS as IMAGE_BAG_TOPICS
from ibr_ros.jobs.process import OUT_TOPICS
from ibr_ros.node_config import TABLES


def _graph_topics() -> set[str]:
    """Every topic of the graph (the tables' topics in the root namespace), the output bag's and the
    NavSatFix topic of bags made from drone photos."""
    names = {t.name for table in TABLES.values() for t in (*table.publishes, *table.subscribes)}
    return (
        {n if n.startswith('/') else '/' + n for n in names}
        | {t for t, _ in OUT_TOPICS.values()}
        | {IMAGE_BAG_TOPICS['navsat']}
    )


def _panels(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict)
    return _panels(node['first']) + _panels(node['second'])


def test_foxglove_layout(repo):
    layout = json.loads((repo / 'config' / 'foxglove_layout.json').read_text())
    panels = _panels(layout['layout'])
    assert sorted(panels) == sorted(layout['configById'])
    kinds = sorted(p.split('!')[0] for p in panels)
    assert kinds == ['3D', 'Image', 'Image', 'Image', 'map']
    topics = _graph_topics()
    three_d = next(c for p, c in layout['configById'].items() if p.startswith('3D!'))
    assert {'/keyframes/points', '/keyframes/frustums'} <= set(three_d['topics'])
    assert three_d['topics']['/keyframes/points']['colorField'] == 'rgb'
    assert three_d['followTf'] == 'map'
    referenced = set(three_d['topics'])
    for p, c in layout['configById'].items():
        if p.startswith('Image!'):
            referenced.add(c['imageMode']['imageTopic'])
        if p.startswith('map!'):
            referenced.add(c['followTopic'])
    assert {'/keyframes/image', '/keyframes/depth', '/novel_view/image/compressed', '/gps/fix'} <= referenced
    # the map follows the fixes ibr process passes through and bags made from photos carry
    maps = [c['followTopic'] for p, c in layout['configById'].items() if p.startswith('map!')]
    assert maps == [OUT_TOPICS['navsat'][0]] == [IMAGE_BAG_TOPICS['navsat']]
    assert referenced <= topics, referenced - topics


def test_rviz_config(repo):
    cfg = yaml.safe_load((repo / 'config' / 'ibr.rviz').read_text())
    manager = cfg['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == 'map'
    displays = manager['Displays']
    classes = {d['Class'].split('/')[-1] for d in displays}
    assert {'TF', 'PointCloud2', 'MarkerArray', 'PoseArray', 'Image', 'Grid'} <= classes
    topics = _graph_topics()
    used = {d['Topic']['Value']: d['Topic'] for d in displays if 'Topic' in d}
    assert set(used) <= topics, set(used) - topics
    assert {'/keyframes/points', '/keyframes/frustums', '/keyframes/image', '/novel_view/image'} <= set(used)
    for name in ('/keyframes/points', '/keyframes/frustums', '/keyframes/poses'):
        assert used[name]['Durability Policy'] == 'Transient Local'  # a late RViz gets the whole model
        assert used[name]['Reliability Policy'] == 'Reliable'
    points = next(d for d in displays if d['Class'].endswith('PointCloud2'))
    assert points['Color Transformer'] == 'RGB8'


def test_viewer_configs_are_installed_with_the_package(repo):
    setup = (repo / 'setup.py').read_text()
    for name in ('config/ibr.rviz', 'config/foxglove_layout.json'):
        assert (repo / name).is_file()
        assert f"'{name}'" in setup  # data_files -> share/ibr_ros/config


def test_vendored_tf2_msgs_is_jazzys_tfmessage(repo):
    """vendor/tf2_msgs (built by `make install` where tf2_msgs has no wheel) defines the same type as
    ROS 2 Jazzy's tf2_msgs, so its /tf and /tf_static match RViz's on a ROS 2 install."""
    import xml.etree.ElementTree as ET

    from ibr_ros.bag.typestore import TYPESTORE

    vendored = (repo / 'vendor' / 'tf2_msgs' / 'msg' / 'TFMessage.msg').read_text()
    jazzy = TYPESTORE.generate_msgdef('tf2_msgs/msg/TFMessage', ros_version=2)[0].split('\n=')[0]
    assert vendored.strip() == jazzy.strip()
    root = ET.parse(repo / 'vendor' / 'tf2_msgs' / 'package.xml').getroot()
    assert root.findtext('name') == 'tf2_msgs'
    assert root.findtext('license') == 'BSD-3-Clause'
    assert (repo / 'vendor' / 'tf2_msgs' / 'LICENSE').is_file()
    assert (repo / 'vendor' / 'tf2_msgs' / 'COLCON_IGNORE').is_file()  # a colcon workspace uses the real one
