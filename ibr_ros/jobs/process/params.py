"""The node parameters ``ibr process`` reads (``config/<node>.yaml`` + a ROS 2 params file) and the core
configurations mapped from them."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypeVar

import yaml

from ibr_ros.core.depth.refine import RefinerConfig
from ibr_ros.core.depth.schedule import ScheduleConfig
from ibr_ros.core.registration.sfm_session import ScaleHint
from ibr_ros.core.render import RenderConfig
from ibr_ros.errors import UserError
from ibr_ros.jobs.process.options import ProcessOptions
from ibr_ros.node_config import DEPTH_REFINER, FRAME_SUBSAMPLER, VIEW_RENDERER, FrameSubsamplerConfig

LOG = logging.getLogger(__package__)  # ibr_ros.jobs.process, as before the split into modules
T = TypeVar('T')


#: The nodes whose parameters ``ibr process`` reads.
NODES = ('frame_subsampler', 'depth_refiner', 'view_renderer')
#: depth_refiner parameters ``ibr process`` sets itself: one worker, the whole flight known.
REFINER_OFFLINE = {'num_workers': 1, 'worker_index': 0, 'refine_again': False}


def _named(node: str, fn: Callable[..., T], *args: object) -> T:
    """``fn(*args)``, its UserError prefixed with ``node`` (whose parameter it names)."""
    try:
        return fn(*args)
    except UserError as exc:
        raise UserError(f'{node} {exc}') from exc


def _section_targets(key: str) -> str | None:
    """The node a params-file section applies to (``'*'`` for wildcards), from its key."""
    key = str(key).strip()
    if key in ('/**', '**'):
        return '*'
    name = key.rstrip('/').rsplit('/', 1)[-1]
    return name or None


def _read_params_file(path: Path) -> list[tuple[str, dict[str, object]]]:
    """``[(target, {name: value})]`` of a ROS 2 params file, in file order."""
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    except OSError as exc:
        raise UserError(f'{path}: cannot read params file: {exc.strerror or exc}') from exc
    except yaml.YAMLError as exc:
        raise UserError(f'{path}: not a YAML params file: {exc}') from exc
    if not isinstance(doc, dict):
        raise UserError(f'{path}: a params file maps node names to {{ros__parameters: ...}}')
    out = []
    for key, section in doc.items():
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise UserError(f'{path}: section {key!r} has no ros__parameters mapping')
        if (target := _section_targets(key)) is not None:
            out.append((target, params))
    return out


def _coerce(path: Path, node: str, name: str, value: object, default: object) -> object:
    """``value`` as the type of the parameter's default (an integer is accepted for a float)."""
    kinds = {bool: 'true or false', float: 'a number', int: 'an integer', list: 'a list'}
    kind = kinds.get(type(default), 'a string')
    bad = UserError(f'{path}: {node}.{name} must be {kind} (default {default!r}), got {value!r}')
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise bad
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad
        return float(value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if isinstance(default, list):
        if not isinstance(value, list):
            raise bad
        return value
    if not isinstance(value, type(default)):
        raise bad
    return value


def load_params(params_file: Path | None = None, config: Path | None = None) -> dict[str, dict[str, object]]:
    """Parameters of :data:`NODES`: ``config/<node>.yaml`` (``config`` folder, default the graph's),
    then the sections of ``params_file`` that apply to each node (wildcards first, in file order).

    Raises:
        UserError: Unreadable file, unknown parameter of a named node, a value of the wrong type.

    """
    from ibr_ros.graph import config_dir

    folder = Path(config) if config is not None else config_dir()
    params: dict[str, dict[str, object]] = {}
    for node in NODES:
        params[node] = {}
        for target, values in _read_params_file(folder / f'{node}.yaml'):
            if target in ('*', node):
                params[node].update(values)
    if params_file is None:
        return params
    sections = _read_params_file(Path(params_file))
    for target, values in sorted(sections, key=lambda s: s[0] != '*'):  # stable: wildcards first
        nodes = NODES if target == '*' else (target,) if target in NODES else ()
        if not nodes:
            LOG.info(
                '%s: section for %s ignored (ibr process runs %s)', params_file, target, ', '.join(NODES)
            )
            continue
        for name, value in values.items():
            known = [n for n in nodes if name in params[n]]
            if not known:
                where = nodes[0] if len(nodes) == 1 else 'any of ' + ', '.join(nodes)
                raise UserError(f'{params_file}: {name!r} is not a parameter of {where}')
            for n in known:
                params[n][name] = _coerce(Path(params_file), n, name, value, params[n][name])
    return params


@dataclass(frozen=True)
class ProcessConfigs:
    """The core configurations of one ``ibr process`` run, built from the node parameters."""

    # target_keyframes: ProcessOptions' when given; 0 = the streaming selector
    subsampler: FrameSubsamplerConfig
    schedule: ScheduleConfig
    flush: bool
    refiner: RefinerConfig
    render: RenderConfig
    out_size: tuple[int, int, float]  # width, height, hfov_deg; 0 = the last keyframe's
    min_valid: float
    view_frame: str
    sfm_mode: str
    sfm_min_keyframes: int
    sfm_max_side: int
    sfm_scale: ScaleHint | None


def process_configs(params: dict[str, dict[str, object]], o: ProcessOptions) -> ProcessConfigs:
    """The core configurations, mapped from the node parameters exactly as the nodes map them."""
    fs, dr, vr = (params[n] for n in NODES)
    try:
        subsampler = FRAME_SUBSAMPLER.config(fs, where='frame_subsampler.')
        refining = _named('depth_refiner', DEPTH_REFINER.config, {**dr, **REFINER_OFFLINE})
        poseless_interval_s = subsampler.poseless_interval_s
        sfm_min_keyframes, sfm_max_side = refining.sfm.min_keyframes, refining.sfm.max_side
        if poseless_interval_s <= 0 or sfm_min_keyframes < 3 or sfm_max_side < 0:
            raise UserError(
                'need frame_subsampler poseless_interval_s > 0, depth_refiner sfm_min_keyframes >= 3 and '
                f'sfm_max_side >= 0, got {poseless_interval_s}, {sfm_min_keyframes}, {sfm_max_side}'
            )
        viewing = VIEW_RENDERER.config(vr, where='view_renderer.')
    except (ValueError, TypeError, KeyError) as exc:
        raise UserError(f'bad node parameters: {exc}') from exc
    size = (
        viewing.width if o.width is None else o.width,
        viewing.height if o.height is None else o.height,
        viewing.hfov_deg if o.hfov_deg is None else o.hfov_deg,
    )
    if size[0] < 0 or size[1] < 0 or not 0 <= size[2] < 180:
        raise UserError(f'novel view size {size[0]}x{size[1]}, hfov {size[2]} deg: need >= 0 and hfov < 180')
    target = subsampler.target_keyframes if o.target_keyframes is None else o.target_keyframes
    if target < 0:
        raise UserError(f'target_keyframes (--target-keyframes) must be >= 0 (0 = off), got {target}')
    return ProcessConfigs(
        subsampler=replace(subsampler, target_keyframes=target),
        schedule=refining.schedule,
        flush=True,  # offline the flight has ended: as live once keyframes/status says so
        refiner=refining.refiner,
        render=viewing.render,
        out_size=size,
        min_valid=viewing.min_valid_fraction,
        view_frame=viewing.frame_id,
        sfm_mode=refining.sfm.mode,
        sfm_min_keyframes=sfm_min_keyframes,
        sfm_max_side=sfm_max_side,
        sfm_scale=refining.sfm.scale,
    )
