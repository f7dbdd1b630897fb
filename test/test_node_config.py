"""Node parameters -> core configurations (shared by the nodes and ``ibr process``)."""

from __future__ import annotations

import pytest
import yaml

from ibr_ros.core.render.renderer import RenderConfig
from ibr_ros.errors import UserError
from ibr_ros.node_config import RENDER_PARAMETERS, render_config


def test_render_parameter_defaults_are_the_core_defaults_and_the_params_file(repo) -> None:
    assert render_config({}) == RenderConfig()
    shipped = yaml.safe_load((repo / 'config' / 'view_renderer.yaml').read_text())['/**']['ros__parameters']
    for name, (default, _, _) in RENDER_PARAMETERS.items():
        assert shipped[name] == default, name
    assert render_config(shipped) == RenderConfig()


def test_zero_switches_the_additions_off_giving_the_papers_renderer() -> None:
    off = {'blend': 'paper', 'depth_split': 0.0, 'coverage_px': 0.0, 'depth_tolerance': 0.0}
    paper = render_config(
        {**off, 'resolution_weight_deg': 0.0, 'depth_lookup_steps': 0, 'min_depth_samples': 10}
    )
    assert paper == RenderConfig.paper()
    assert render_config({'depth_split': 0.05, 'n_views': 2}).depth_split == 0.05


@pytest.mark.parametrize(
    ('values', 'match'),
    [
        ({'blend': 'max'}, "blend must be 'paper', 'soft' or 'ulr', got 'max'"),
        ({'n_views': 5}, 'n_views must be 1..4, got 5'),
        ({'coverage_px': -1.0}, r'coverage_px must be None \(off\) or > 0, got -1.0'),
        ({'depth_tolerance': 'wide'}, 'bad view_renderer parameter value'),
        ({'depth_lookup_max_px': 0.0}, 'depth_lookup_max_px > 0'),
    ],
)
def test_bad_render_parameters_are_user_errors_naming_them(values, match) -> None:
    with pytest.raises(UserError, match=match):
        render_config(values)
