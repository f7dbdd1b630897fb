# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr view``: the nodes it starts, and bags it refuses (no DDS: nothing is started)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from web_model import model_views, write_model_bag

from ibr_ros.cli.main import build_parser, main
from ibr_ros.cli.view import view_nodes


def _args(*argv: str):
    return build_parser().parse_args(['view', *argv])


def test_live_view_starts_the_viewer_alone(tmp_path) -> None:
    (spec,) = view_nodes(_args('--port', '9000', '--host', '0.0.0.0'), tmp_path / 'url')
    assert spec.name == 'web_viewer'
    assert spec.params['port'] == 9000
    assert spec.params['host'] == '0.0.0.0'
    assert spec.params['url_file'] == str(tmp_path / 'url')


def test_bag_view_serves_the_model_of_an_output_bag(tmp_path) -> None:
    bag = write_model_bag(tmp_path / 'bag', model_views((64, 36))[:2])
    renderer, player, viewer = view_nodes(_args('--bag', str(bag), '--width', '320'), tmp_path / 'url')
    assert (renderer.name, player.name, viewer.name) == ('view_renderer', 'bag_player', 'web_viewer')
    assert renderer.params == {'width': 320, 'height': 360, 'hfov_deg': 0.0, 'blend': 'stable'}
    model = ['/keyframes/image', '/keyframes/camera_info', '/keyframes/pose', '/keyframes/depth']
    assert player.params['topics'] == model
    assert player.params['linger_s'] == -1.0  # a late or restarted renderer still gets the model
    assert player.params['wait_topics'] == model


def test_a_bag_without_a_model_is_refused(repo, capsys) -> None:
    bag = repo / 'bags' / 'synth_orbit_s0'  # committed: an input bag, no ibr process output
    assert main(['view', '--bag', str(bag)]) == 2
    err = capsys.readouterr().err
    assert 'no /keyframes/image' in err
    assert 'not an ibr process output bag' in err
