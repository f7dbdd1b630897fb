# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Start the ibr_ros node graph as separate processes, where ``ros2 launch`` is not available.

Each node runs as ``python -P -m ibr_ros.launch_entry <name> --ros-args --params-file
<config>/<name>.yaml`` (the installed package, not a checkout in the working directory; the same
parameters as ``launch/ibr_graph.launch.py``) plus per-node overrides. :meth:`Graph.stop` sends
SIGINT to every node, then SIGTERM and SIGKILL to those still running after ``grace_s``; a node
whose parent dies (even by SIGKILL) gets SIGTERM from the kernel, so no node outlives its graph.
:func:`camera_topics` names the topics of a bag that the frame_subsampler subscribes, for the
bag_player's ``wait_topics``.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    'GRAPH_NODES',
    'Graph',
    'NodeSpec',
    'camera_topics',
    'claim_domain',
    'config_dir',
    'die_with_parent',
    'node_command',
    'wait_for_subsampler',
]

LOG = logging.getLogger(__name__)

#: The nodes of the graph, in start order.
GRAPH_NODES = ('bag_player', 'frame_subsampler', 'depth_refiner', 'view_renderer', 'scene_viz')


def config_dir() -> Path:
    """Folder of the default parameter files: the installed share/ibr_ros/config (found through the
    ament index, else under this interpreter's prefix: a pip-installed venv used without
    AMENT_PREFIX_PATH), else the checkout's."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            installed = Path(get_package_share_directory('ibr_ros')) / 'config'
            if installed.is_dir():
                return installed
        except (PackageNotFoundError, ValueError, OSError):
            pass
    except ImportError:
        pass
    checkout = Path(__file__).resolve().parents[1] / 'config'
    in_prefix = Path(sys.prefix) / 'share' / 'ibr_ros' / 'config'
    if not checkout.is_dir() and in_prefix.is_dir():
        return in_prefix
    return checkout


def camera_topics(bag: Path | str, image_transport: str = 'auto', pose_source: str = 'auto') -> list[str]:
    """The topics of ``bag`` that a frame_subsampler with these settings subscribes (in the root
    namespace, unremapped): its image topic, ``/camera/camera_info`` and, unless ``pose_source`` is
    ``none``, ``/camera/pose``; what the bag_player's ``wait_topics`` should name.

    Raises:
        UserError: The bag has none of the image topics that ``image_transport`` takes.

    """
    from ibr_ros.bag import open_bag
    from ibr_ros.core.flight.status import IMAGE_TRANSPORTS
    from ibr_ros.errors import UserError

    with open_bag(bag) as reader:
        names = set(reader.topics)
    wanted = ['/' + t for t in IMAGE_TRANSPORTS.get(image_transport, IMAGE_TRANSPORTS['auto'])]
    image = [t for t in wanted if t in names][:1]
    if not image:
        raise UserError(
            f'{bag}: no {" or ".join(wanted)} topic for the frame_subsampler (image_transport '
            f'{image_transport}); remap the camera topics of the bag (bag_player remap)'
        )
    others = ('/camera/camera_info',) + (('/camera/pose',) if pose_source != 'none' else ())
    return image + [t for t in others if t in names]


def wait_for_subsampler(bag: Path | str, image_transport: str = 'auto', pose_source: str = 'auto') -> dict:
    """bag_player parameters that start playback once a frame_subsampler with these settings
    subscribes ``bag``'s camera topics (:func:`camera_topics`), however long that takes."""
    return {
        'wait_for_subscribers': 1,
        'wait_timeout_s': 0.0,
        'wait_topics': camera_topics(bag, image_transport, pose_source),
    }


def claim_domain(first: int) -> tuple[int, socket.socket]:
    """A ROS_DOMAIN_ID of this host's own, from ``first`` (cycling through 1..100), and its lock.

    Fast DDS gives domain d the ports 7400 + 250 d + 0..249 and uses the last ones only for a 119th
    participant; binding 127.0.0.1:(7400 + 250 d + 249) is this process's lock on d (held as long as
    the returned socket is open), so two isolated runs on one machine never share a domain.
    """
    for k in range(100):
        domain = 1 + (first - 1 + k) % 100
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(('127.0.0.1', 7400 + 250 * domain + 249))
        except OSError:
            sock.close()
            continue
        return domain, sock
    raise RuntimeError('no free ROS_DOMAIN_ID in 1..100 (all lock ports are bound)')


def _libc_prctl() -> Callable[..., int] | None:
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # not Linux
        return None


_PRCTL = _libc_prctl()  # looked up here: the child between fork and exec only calls it


def die_with_parent() -> None:
    """In the child before exec: SIGTERM when the parent dies (Linux prctl PR_SET_PDEATHSIG)."""
    if _PRCTL is not None:
        _PRCTL(1, signal.SIGTERM, 0, 0, 0)


def _ros_value(value: object) -> str:
    """``value`` as the YAML text of a ``-p name:=value`` argument; a string that YAML would read as
    something else (``'1'``, ``'true'``, ``''``) is quoted."""
    import yaml

    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_ros_value(v) for v in value) + ']'
    if isinstance(value, str):
        try:
            plain = yaml.safe_load(value) == value
        except yaml.YAMLError:
            plain = False
        return value if plain else "'" + value.replace("'", "''") + "'"
    return str(value)


@dataclass(frozen=True)
class NodeSpec:
    """One node process: executable name, parameter overrides, remappings, optional node name.

    Parameter files use the ``/**:`` wildcard key, so they also apply to renamed nodes (e.g. the
    sharded ``depth_refiner_1``).
    """

    name: str
    params: Mapping[str, object] = field(default_factory=dict)
    remaps: Mapping[str, str] = field(default_factory=dict)
    node_name: str | None = None

    @property
    def label(self) -> str:
        return self.node_name or self.name


def node_command(spec: NodeSpec, *, config: Path | None = None, python: str = sys.executable) -> list[str]:
    """Command line of one node process."""
    isolated = ['-P'] if sys.version_info >= (3, 11) else []  # no working directory on sys.path
    cmd = [python, *isolated, '-m', 'ibr_ros.launch_entry', spec.name, '--ros-args']
    params_file = (config or config_dir()) / f'{spec.name}.yaml'
    if params_file.is_file():
        cmd += ['--params-file', str(params_file)]
    for key, value in spec.params.items():
        cmd += ['-p', f'{key}:={_ros_value(value)}']
    for src, dst in spec.remaps.items():
        cmd += ['-r', f'{src}:={dst}']
    if spec.node_name:
        cmd += ['-r', f'__node:={spec.node_name}']
    return cmd


class Graph:
    """Node processes started together and stopped together (a context manager)."""

    def __init__(
        self,
        nodes: Sequence[NodeSpec],
        *,
        config: Path | None = None,
        env: Mapping[str, str] | None = None,
        log_dir: Path | None = None,
        grace_s: float = 30.0,  # a depth_refiner finishes its current MVS or SfM step first
    ) -> None:
        self.specs = list(nodes)
        self.config = config
        self.env = dict(os.environ if env is None else env)
        self.log_dir = log_dir
        self.grace_s = grace_s
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self) -> Graph:
        """Start every node (in order); their output goes to ``log_dir/<name>.log`` or is inherited."""
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
        for spec in self.specs:
            out = open(self.log_dir / f'{spec.label}.log', 'w') if self.log_dir else None  # noqa: SIM115
            cmd = node_command(spec, config=self.config)
            LOG.info('starting %s: %s', spec.label, ' '.join(cmd))
            self.procs[spec.label] = subprocess.Popen(
                cmd,
                env=self.env,
                stdout=out,
                stderr=subprocess.STDOUT if out else None,
                preexec_fn=die_with_parent if sys.platform.startswith('linux') else None,
            )
            if out is not None:
                out.close()
        return self

    def poll(self) -> dict[str, int | None]:
        """Exit status of every node (None while running)."""
        return {name: p.poll() for name, p in self.procs.items()}

    def wait_for(self, name: str, timeout: float | None = None) -> int | None:
        """Wait until node ``name`` exits; its exit status, or None on timeout."""
        try:
            return self.procs[name].wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self) -> dict[str, int | None]:
        """SIGINT every running node, wait up to ``grace_s``, then SIGTERM and finally SIGKILL."""
        for sig, wait in ((signal.SIGINT, self.grace_s), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            running = [p for p in self.procs.values() if p.poll() is None]
            if not running:
                break
            for p in running:
                p.send_signal(sig)
            deadline = time.monotonic() + wait
            for p in running:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    p.wait(timeout=max(0.0, deadline - time.monotonic()))
        return self.poll()

    def __enter__(self) -> Graph:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
