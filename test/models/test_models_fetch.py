# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr models fetch``: download, sha256 verification and errors against a local HTTP server."""

from __future__ import annotations

import argparse
import functools
import hashlib
import http.server
import socket
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from ibr_ros.cli import models as models_cli
from ibr_ros.errors import UserError
from ibr_ros.models.registry import MODELS, ModelEntry, fetch_model, sha256_file

PAYLOAD = bytes(range(256)) * 4000  # ~1 MB, more than one read chunk


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        pass


@pytest.fixture
def server(tmp_path: Path) -> Iterator[str]:
    """Base URL of an HTTP server on 127.0.0.1 serving ``model.onnx`` (PAYLOAD)."""
    root = tmp_path / 'www'
    root.mkdir()
    (root / 'model.onnx').write_bytes(PAYLOAD)
    httpd = http.server.ThreadingHTTPServer(('127.0.0.1', 0), functools.partial(_Quiet, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f'http://127.0.0.1:{httpd.server_address[1]}'
    finally:
        httpd.shutdown()
        httpd.server_close()


def _entry(url: str, sha: str) -> ModelEntry:
    return ModelEntry(
        name='stand_in', url=url, sha256=sha, filename='stand_in.onnx', preset='midas_v21_small'
    )


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_fetch_downloads_and_verifies(server: str, tmp_path: Path) -> None:
    sha = hashlib.sha256(PAYLOAD).hexdigest()
    seen: list[int] = []
    path = fetch_model(
        _entry(f'{server}/model.onnx', sha), tmp_path / 'cache', progress=lambda d, t: seen.append(d)
    )
    assert path == tmp_path / 'cache' / 'stand_in.onnx'
    assert path.read_bytes() == PAYLOAD
    assert seen[-1] == len(PAYLOAD)
    assert [p.name for p in path.parent.iterdir()] == ['stand_in.onnx']  # no temporary left
    # A second fetch reuses the verified file without the network.
    again = fetch_model(_entry('http://127.0.0.1:1/unreachable', sha), tmp_path / 'cache')
    assert again == path


def test_checksum_mismatch_names_both_and_leaves_nothing(server: str, tmp_path: Path) -> None:
    wrong = '0' * 64
    cache = tmp_path / 'cache'
    with pytest.raises(UserError, match='checksum mismatch') as err:
        fetch_model(_entry(f'{server}/model.onnx', wrong), cache)
    assert wrong in str(err.value)
    assert hashlib.sha256(PAYLOAD).hexdigest() in str(err.value)
    assert list(cache.iterdir()) == []


def test_unreachable_and_http_errors(server: str, tmp_path: Path) -> None:
    url = f'http://127.0.0.1:{_closed_port()}/model.onnx'
    cache = tmp_path / 'cache'
    with pytest.raises(UserError, match=f'cannot reach URL: {url}'):
        fetch_model(_entry(url, '0' * 64), cache, timeout_s=5)
    with pytest.raises(UserError, match='HTTP 404'):
        fetch_model(_entry(f'{server}/missing.onnx', '0' * 64), cache)
    assert list(cache.iterdir()) == []


def test_cli_fetch(
    server: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    sha = hashlib.sha256(PAYLOAD).hexdigest()
    monkeypatch.setitem(MODELS, 'stand_in', _entry(f'{server}/model.onnx', sha))
    parser = argparse.ArgumentParser()
    models_cli.register(parser.add_subparsers(dest='command'))
    args = parser.parse_args(['models', 'fetch', 'stand_in', '--to', str(tmp_path), '--no-progress'])
    assert args.func(args) == 0
    assert sha256_file(tmp_path / 'stand_in.onnx') == sha
    assert str(tmp_path / 'stand_in.onnx') in capsys.readouterr().out
    args = parser.parse_args(['models', 'fetch', 'nope', '--to', str(tmp_path)])
    with pytest.raises(UserError, match='unknown model'):
        args.func(args)
    args = parser.parse_args(['models', 'list'])
    assert args.func(args) == 0
    assert 'midas_v21_small' in capsys.readouterr().out


def test_registry_entries_are_well_formed() -> None:
    from ibr_ros.core.depth.mono import PRESETS

    for e in MODELS.values():
        assert e.url.startswith('https://')
        assert len(e.sha256) == 64
        int(e.sha256, 16)
        assert e.preset in PRESETS
        assert replace(e, name='x').name == 'x'
