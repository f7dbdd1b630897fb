# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The web viewer's server without ROS or a browser: an aiohttp client plays the page, the test plays
the node (keyframes and replies posted to the server's loop, queries recorded)."""

from __future__ import annotations

import asyncio
import json
import queue
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ibr_ros.core.geometry.transforms import look_at
from ibr_ros.core.navigation import Query
from ibr_ros.core.render import ReplyStatus
from ibr_ros.node_config.web_viewer import WEB_VIEWER
from ibr_ros.web import ViewerServer, unpack_frame

aiohttp = pytest.importorskip('aiohttp')

KEYFRAMES = [look_at([10.0 * i, 0.0, 30.0], [10.0 * i, 20.0, 0.0]) for i in range(3)]
ANSWERED = ReplyStatus('answered', '', 1.0, 0.7, 'ok', ('1',), 12.5)


class Node:
    """What the node does for the server: records the queries; counts bad input."""

    def __init__(self) -> None:
        self.queries: queue.Queue[Query] = queue.Queue()
        self.bad: list[tuple[str, str]] = []
        self.forgotten: list[int] = []

    def publish(self, q: Query) -> None:
        self.queries.put(q)

    def query(self) -> Query:
        return self.queries.get(timeout=10)


class Log:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def info(self, message: str) -> None:
        self.lines.append(message)

    def warning(self, message: str) -> None:
        self.lines.append(message)


@pytest.fixture
def served(tmp_path):
    cfg = replace(WEB_VIEWER.config({'port': 0}), save_dir=str(tmp_path / 'saved'))
    node = Node()
    server = ViewerServer(
        cfg, node.publish, node.forgotten.append, lambda r, d: node.bad.append((r, d)), Log()
    )
    url = server.start()
    for i, t in enumerate(KEYFRAMES):
        server.post(server.on_keyframe, 1000 + i, t)
    yield server, node, url
    server.stop()


def _reply(server: ViewerServer, q: Query, status: ReplyStatus = ANSWERED, value: int = 0) -> np.ndarray:
    rgb = np.full((36, 64, 3), value, np.uint8)
    if status.published:
        server.post(server.on_image, q.stamp, b'JPEG' + bytes([value]), rgb)
    server.post(server.on_status, q.stamp, status)
    return rgb


async def _next(ws, kind: str | None = None):
    """The next message of the page: (header, jpeg) for a view, the dict for JSON (of ``kind``)."""
    while True:
        msg = await asyncio.wait_for(ws.receive(), 10)
        if msg.type == aiohttp.WSMsgType.BINARY:
            if kind in (None, 'frame'):
                return unpack_frame(msg.data)
            continue
        data = json.loads(msg.data)
        if kind is None or data['type'] == kind:
            return data


def test_page_flight_one_query_in_flight_newest_waits_views_acknowledged(served) -> None:
    server, node, url = served

    async def page() -> None:
        async with aiohttp.ClientSession() as http:
            async with http.get(url) as r:
                assert r.status == 200
                assert '<canvas id="view"' in await r.text()
            async with http.get(url + 'viewer.js') as r:
                assert r.status == 200
                assert r.content_type == 'text/javascript'
            async with http.ws_connect(url + 'ws') as ws:
                hello = await _next(ws)  # the keyframes were posted before the page connected
                assert hello['type'] == 'hello'
                assert len(hello['keyframes']) == 3
                q0 = await asyncio.to_thread(node.query)  # the start pose: the first keyframe
                np.testing.assert_allclose(q0.t_wc, KEYFRAMES[0])
                for seq in (1, 2, 3):  # while q0 renders: 1 and 2 are superseded by 3
                    await ws.send_json({'type': 'fly', 'seq': seq, 'forward': 1, 'dt': 0.1})
                await ws.send_json({'type': 'fly', 'seq': 4, 'forward': 1})  # dt 0: nothing
                await ws.send_json({'type': 'save'})  # answered in order: the inputs are in
                assert (await _next(ws, 'error'))['message'] == 'no view to save yet'
                _reply(server, q0, value=7)
                header, jpeg = await _next(ws, 'frame')
                assert (header['stamp'], header['seq'], jpeg) == (str(q0.stamp), 0, b'JPEG\x07')
                q1 = await asyncio.to_thread(node.query)
                assert q1.seq == 3
                speed = hello['speed_mps']  # 2 keyframe spacings (10 m) per second
                assert speed == pytest.approx(20.0)
                assert q1.t_wc[1, 3] - q0.t_wc[1, 3] == pytest.approx(
                    0.3 * speed * 20 / np.hypot(20, 30), rel=1e-6
                )
                assert node.queries.empty()
                # The view of q1 waits until the page has shown q0's.
                _reply(server, q1, value=8)
                await ws.send_json({'type': 'fly', 'seq': 5, 'right': 1, 'dt': 0.1})
                q2 = await asyncio.to_thread(node.query)  # the renderer is free: sent at once
                _reply(server, q2, status=replace(ANSWERED, render_ms=3.0), value=9)  # replaces q1's
                await ws.send_json({'type': 'fly', 'seq': 6, 'right': 1, 'dt': 0.1})
                q3 = await asyncio.to_thread(node.query)
                await ws.send_json({'type': 'shown', 'stamp': header['stamp']})
                header2, jpeg2 = await _next(ws, 'frame')
                assert (header2['stamp'], jpeg2) == (str(q2.stamp), b'JPEG\x09')
                (client,) = server.clients
                assert client.session.stats()['superseded_views'] == 1  # q1's view, never sent
                assert header2['stats']['superseded_queries'] == 2
                # A refusal reaches the page as a status, and frees the renderer for the next pose.
                _reply(server, q3, status=ReplyStatus('refused', 'unrenderable', 0.0, 0.7, 'too far'))
                status = await _next(ws, 'status')
                assert (status['stamp'], status['reason']) == (str(q3.stamp), 'unrenderable')
                # A map click on the third keyframe jumps there.
                kf = hello['keyframes'][2]
                await ws.send_json({'type': 'jump', 'seq': 7, 'u': kf['u'] + 3, 'v': kf['v']})
                q4 = await asyncio.to_thread(node.query)
                np.testing.assert_allclose(q4.t_wc, KEYFRAMES[2])
                # Save writes the view last sent to the page, lossless, and its pose.
                await ws.send_json({'type': 'save'})
                saved = await _next(ws, 'saved')
                assert Path(saved['path']).name == f'view_{q2.stamp}.png'
                meta = json.loads(Path(saved['path']).with_suffix('.json').read_text())
                np.testing.assert_allclose(meta['t_wc'], q2.t_wc)

    asyncio.run(page())
    assert not node.bad
    assert len(node.forgotten) >= 4  # the node stops decoding replies of finished queries


@pytest.mark.parametrize(
    ('msg', 'match'),
    [
        ('not json', 'Expecting value'),
        ('[1, 2]', 'must be a JSON object'),
        ('{"type": "fly", "seq": 1, "forward": 5, "dt": 0.1}', 'input field forward must be -1..1, got 5'),
        ('{"type": "fly", "seq": -1}', 'seq must be a non-negative integer'),
        ('{"type": "shown", "stamp": 12}', 'stamp must be a string of digits'),
        ('{"type": "warp"}', "unknown page message type 'warp'"),
    ],
)
def test_bad_page_messages_are_counted_logged_and_answered(served, msg, match) -> None:
    _, node, url = served

    async def page() -> dict:
        async with aiohttp.ClientSession() as http, http.ws_connect(url + 'ws') as ws:
            await ws.send_str(msg)
            return await _next(ws, 'error')

    error = asyncio.run(page())
    assert match in error['message']
    assert node.bad[0][0] == 'page_input'
    assert match in node.bad[0][1]


def test_a_websocket_from_another_site_is_refused(served) -> None:
    _, node, url = served

    async def page() -> int:
        async with aiohttp.ClientSession() as http:
            try:
                async with http.ws_connect(url + 'ws', headers={'Origin': 'http://evil.example'}):
                    return 101
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status

    assert asyncio.run(page()) == 403
    assert node.bad[0][0] == 'origin'


def test_the_address_in_use_is_a_user_error(served) -> None:
    from ibr_ros.errors import UserError

    server, node, url = served
    port = int(url.rsplit(':', 1)[1].strip('/'))
    other = ViewerServer(replace(server.cfg, port=port), node.publish, node.forgotten.append, print, Log())
    with pytest.raises(UserError, match=f'cannot serve on 127.0.0.1:{port}'):
        other.start()
