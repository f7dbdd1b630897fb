# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""The web viewer's server: the page and one WebSocket per page, on an asyncio loop in a thread.

aiohttp serves ``/`` (``static/index.html``), ``/viewer.js``, ``/viewer.css`` and ``/ws``. Each
WebSocket is one :class:`~ibr_ros.core.navigation.ViewSession`: the page sends its input (``fly``,
``jump``, ``shown``, ``save`` JSON messages), the server answers with JSON text messages (``hello``,
``map``, ``status``, ``saved``, ``error``) and binary views (:func:`pack_frame`: a 4-byte big-endian
header length, the JSON header, the JPEG). The ROS side (the node) calls :meth:`ViewerServer.post`
from its own thread to hand keyframes and replies to the loop, and the server calls ``publish`` from
the loop's thread to send a query. A WebSocket whose Origin is another site is refused (403), so
another web page in the browser cannot drive the viewer.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

import numpy as np
from numpy.typing import NDArray

from ibr_ros.core.navigation import (
    Motion,
    NavigationError,
    Navigator,
    Query,
    TopDownMap,
    ViewSession,
    scene_speed,
)
from ibr_ros.core.render import ReplyStatus
from ibr_ros.errors import UserError
from ibr_ros.io.atomic import write_atomic
from ibr_ros.node_config.web_viewer import WebViewerConfig

__all__ = ['Reply', 'ViewerServer', 'pack_frame', 'unpack_frame']

#: After a ``no_model`` refusal (the renderer has not received a keyframe yet), ask again this late (s).
NO_MODEL_RETRY_S = 0.5

STATIC = {'/': ('index.html', 'text/html'), '/viewer.js': ('viewer.js', 'text/javascript'),
          '/viewer.css': ('viewer.css', 'text/css')}  # fmt: skip


class Log(Protocol):
    def info(self, message: str) -> Any: ...
    def warning(self, message: str) -> Any: ...


def pack_frame(header: dict[str, Any], jpeg: bytes) -> bytes:
    """A binary view message: 4-byte big-endian header length, the JSON header, the JPEG."""
    head = json.dumps(header, separators=(',', ':')).encode()
    return struct.pack('>I', len(head)) + head + jpeg


def unpack_frame(data: bytes) -> tuple[dict[str, Any], bytes]:
    """The header and JPEG of :func:`pack_frame`'s message."""
    (n,) = struct.unpack('>I', data[:4])
    return json.loads(data[4 : 4 + n]), data[4 + n :]


@dataclass
class Reply:
    """A renderer reply being assembled: the status and (when it announces one) the view."""

    status: ReplyStatus | None = None
    jpeg: bytes | None = None
    rgb: NDArray[np.uint8] | None = None

    @property
    def complete(self) -> bool:
        return self.status is not None and (not self.status.published or self.jpeg is not None)


@dataclass
class _Shown:
    """The view last sent to a page (what its save button writes)."""

    stamp: int
    rgb: NDArray[np.uint8]
    t_wc: NDArray[np.float64]


class _Client:
    """One page: its session, its send queue and its timers."""

    def __init__(self, ws: Any, session: ViewSession[tuple[bytes, _Shown]]) -> None:
        self.ws = ws
        self.session = session
        self.out: asyncio.Queue[str | bytes | None] = asyncio.Queue()
        self.last: _Shown | None = None
        self.timer: asyncio.TimerHandle | None = None

    def send_json(self, msg: dict[str, Any]) -> None:
        self.out.put_nowait(json.dumps(msg, separators=(',', ':')))


class ViewerServer:
    """The HTTP/WebSocket server (see module docstring).

    ``publish(query)`` sends a query (called on the loop's thread); ``forget(stamp)`` tells the node
    a query's reply is complete or given up; ``bad(reason, detail)`` counts and logs rejected input.
    """

    def __init__(
        self,
        cfg: WebViewerConfig,
        publish: Callable[[Query], None],
        forget: Callable[[int], None],
        bad: Callable[[str, str], None],
        log: Log,
    ) -> None:
        self.cfg = cfg
        self.publish = publish
        self.forget = forget
        self.bad = bad
        self.log = log
        self.map = TopDownMap(cfg.map_px, up=cfg.up_axis)
        self.speed_mps = cfg.default_speed_mps
        self.clients: set[_Client] = set()
        self.owner: dict[int, _Client] = {}  # query stamp -> the page that asked
        self.replies: dict[int, Reply] = {}
        self.lost = 0
        self.frame_id = cfg.query_frame  # of the poses (the node sets the keyframes' when it is empty)
        self._last_stamp = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: Any = None
        self._tasks: set[asyncio.Future[None]] = set()
        static = resources.files('ibr_ros.web') / 'static'
        self._pages = {route: (static / name).read_bytes() for route, (name, _) in STATIC.items()}
        self.url = ''

    # -- life cycle (any thread) --------------------------------------------------------------------
    def start(self) -> str:
        """Serve in a new thread; the URL once listening (UserError when the address is taken)."""
        ready: concurrent.futures.Future[str] = concurrent.futures.Future()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, args=(ready,), name='web_viewer_http', daemon=True)
        self._thread.start()
        self.url = ready.result()
        return self.url

    def stop(self) -> None:
        """Close every page's socket and the server; join the thread."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=10.0)

    def post(self, func: Callable[..., None], *args: Any) -> None:
        """Run ``func(*args)`` on the server's loop (from the node's thread)."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # closed meanwhile (shutting down)
                loop.call_soon_threadsafe(func, *args)

    def _run(self, ready: concurrent.futures.Future[str]) -> None:
        loop = self._loop
        assert loop is not None
        asyncio.set_event_loop(loop)
        try:
            url = loop.run_until_complete(self._serve())
        except OSError as exc:
            ready.set_exception(UserError(f'cannot serve on {self.cfg.host}:{self.cfg.port}: {exc}'))
            loop.close()
            return
        except BaseException as exc:
            ready.set_exception(exc)
            loop.close()
            return
        ready.set_result(url)
        try:
            loop.run_forever()
        finally:
            loop.run_until_complete(self._close())
            loop.close()

    async def _serve(self) -> str:
        from aiohttp import web

        app = web.Application()
        app.router.add_get('/ws', self._websocket)
        for route, (_, ctype) in STATIC.items():
            app.router.add_get(route, self._page(route, ctype))
        app.router.add_get('/favicon.ico', self._no_icon)
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.cfg.host, self.cfg.port)
        await site.start()
        sockets = [s for s in self._runner.addresses if isinstance(s, tuple)]
        port = sockets[0][1] if sockets else self.cfg.port
        host = f'[{self.cfg.host}]' if ':' in self.cfg.host else self.cfg.host
        return f'http://{host}:{port}/'

    async def _close(self) -> None:
        for c in list(self.clients):
            c.out.put_nowait(None)
            await c.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    @staticmethod
    async def _no_icon(request: Any) -> Any:
        from aiohttp import web

        return web.Response(status=204)

    def _page(self, route: str, ctype: str) -> Callable[[Any], Any]:
        from aiohttp import web

        async def handler(request: Any) -> Any:
            return web.Response(body=self._pages[route], content_type=ctype,
                                headers={'Cache-Control': 'no-store'})  # fmt: skip

        return handler

    # -- pages --------------------------------------------------------------------------------------
    async def _websocket(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        origin = request.headers.get('Origin')
        if origin is not None and urlsplit(origin).netloc != request.host:
            self.bad('origin', f'WebSocket from origin {origin!r} refused (serving {request.host})')
            raise web.HTTPForbidden(text='cross-origin WebSocket refused')
        ws = web.WebSocketResponse(heartbeat=None, max_msg_size=1 << 16)
        await ws.prepare(request)
        client = _Client(ws, ViewSession(self._stamp))
        self.clients.add(client)
        writer = asyncio.ensure_future(self._writer(client))
        self.log.info(f'page connected from {request.remote} ({len(self.clients)} open)')
        client.send_json({'type': 'hello', **self._map_msg()})
        self._start(client)
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._on_page(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self.bad('page_input', 'a binary message from the page, ignored')
        finally:
            self.clients.discard(client)
            if client.timer is not None:
                client.timer.cancel()
            client.out.put_nowait(None)
            await writer
            for stamp in [s for s, c in self.owner.items() if c is client]:
                del self.owner[stamp]
                self.replies.pop(stamp, None)
                self.forget(stamp)
            stats = client.session.stats()
            self.log.info(f'page disconnected ({len(self.clients)} open); its counters: {stats}')
        return ws

    async def _writer(self, client: _Client) -> None:
        while (item := await client.out.get()) is not None:
            if client.ws.closed:
                continue  # drained until the reader ends
            try:
                if isinstance(item, bytes):
                    await client.ws.send_bytes(item)
                else:
                    await client.ws.send_str(item)
            except ConnectionError:
                pass  # the page went away; the reader loop ends

    def _stamp(self) -> int:
        self._last_stamp = max(time.time_ns(), self._last_stamp + 1)
        return self._last_stamp

    def _start(self, client: _Client) -> None:
        """Start ``client`` flying at the first keyframe once there is one."""
        if client.session.navigator is not None or not self.map.poses:
            return
        first = self.map.poses[min(self.map.poses)]
        nav = Navigator(
            first,
            speed_mps=self.speed_mps,
            turn_rate_deg_s=self.cfg.turn_rate_deg_s,
            drag_deg_per_px=self.cfg.drag_deg_per_px,
            fast_factor=self.cfg.fast_factor,
            up=self.cfg.up_axis,
        )
        self._query(client, client.session.start(nav))

    def _on_page(self, client: _Client, text: str) -> None:
        """One JSON message of a page (bad ones are counted, logged and answered with an error)."""
        s = client.session
        try:
            msg = json.loads(text)
            if not isinstance(msg, dict):
                raise NavigationError(f'a page message must be a JSON object, got {text[:60]!r}')
            kind = msg.get('type')
            seq = msg.get('seq', 0)
            if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
                raise NavigationError(f'input field seq must be a non-negative integer, got {seq!r}')
            if kind == 'fly':
                self._query(client, s.fly(Motion.from_json(msg), seq))
            elif kind == 'shown':
                stamp = msg.get('stamp')  # a string: JSON numbers in the page are doubles
                if not isinstance(stamp, str) or not stamp.isdigit():
                    raise NavigationError(f'input field stamp must be a string of digits, got {stamp!r}')
                if (nxt := s.shown(int(stamp))) is not None:
                    client.out.put_nowait(nxt[1][0])
                    client.last = nxt[1][1]
            elif kind == 'jump':
                u, v = msg.get('u'), msg.get('v')
                if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (u, v)):
                    raise NavigationError(f'input fields u, v must be numbers, got {u!r}, {v!r}')
                stamp = self.map.pick(float(u), float(v))  # type: ignore[arg-type]  # checked above
                if stamp is not None:
                    self._query(client, s.jump(self.map.poses[stamp], seq))
            elif kind == 'save':
                self._save(client)
            else:
                raise NavigationError(f'unknown page message type {kind!r}')
        except (ValueError, NavigationError) as exc:  # json.JSONDecodeError is a ValueError
            self.bad('page_input', str(exc))
            client.send_json({'type': 'error', 'message': str(exc)})

    def _query(self, client: _Client, q: Query | None) -> None:
        if q is None:
            return
        self.owner[q.stamp] = client
        self.replies[q.stamp] = Reply()
        self.publish(q)
        if self.cfg.reply_timeout_s > 0 and self._loop is not None:
            if client.timer is not None:
                client.timer.cancel()
            client.timer = self._loop.call_later(self.cfg.reply_timeout_s, self._expire, client, q.stamp)

    def _expire(self, client: _Client, stamp: int) -> None:
        if self.owner.get(stamp) is not client:
            return
        self.lost += 1
        self.log.warning(
            f'query {stamp} ns: no reply within {self.cfg.reply_timeout_s:g} s (is a view_renderer '
            f'running?), given up ({self.lost} so far); sending the newest pose'
        )
        client.send_json({'type': 'status', 'stamp': str(stamp), 'result': 'lost', 'reason': 'timeout',
                          'message': f'no reply within {self.cfg.reply_timeout_s:g} s'})  # fmt: skip
        self._finish(client, stamp, 'lost', retry=True)

    def _finish(self, client: _Client, stamp: int, result: str, retry: bool = False) -> None:
        """Query ``stamp`` is over; send the waiting one, else with ``retry`` the current pose again."""
        del self.owner[stamp]
        self.replies.pop(stamp, None)
        self.forget(stamp)
        nxt = client.session.replied(stamp, result)
        if nxt is None and retry:
            nxt = client.session.refresh(client.session.last_seq)
        self._query(client, nxt)

    def _retry(self, client: _Client) -> None:
        if client in self.clients and client.session.in_flight is None:
            self._query(client, client.session.refresh(client.session.last_seq))

    def _save(self, client: _Client) -> None:
        shown = client.last
        if shown is None:
            client.send_json({'type': 'error', 'message': 'no view to save yet'})
            return
        folder = Path(self.cfg.save_dir)

        def write() -> str:
            import cv2

            folder.mkdir(parents=True, exist_ok=True)
            ok, png = cv2.imencode('.png', np.ascontiguousarray(shown.rgb[..., ::-1]))
            if not ok:
                raise OSError('PNG encoding failed')
            path = folder / f'view_{shown.stamp}.png'
            write_atomic(path, png.tobytes())
            meta = {'stamp_ns': shown.stamp, 't_wc': shown.t_wc.tolist(), 'frame_id': self.frame_id}
            write_atomic(path.with_suffix('.json'), (json.dumps(meta, indent=1) + '\n').encode())
            return str(path)

        async def run() -> None:
            assert self._loop is not None
            try:
                path = await self._loop.run_in_executor(None, write)
            except OSError as exc:
                self.bad('save', f'cannot save the view in {folder}: {exc}')
                client.send_json({'type': 'error', 'message': f'cannot save: {exc}'})
                return
            self.log.info(f'saved the view in {path}')
            client.send_json({'type': 'saved', 'path': path})

        task = asyncio.ensure_future(run())
        self._tasks.add(task)  # referenced until done (the loop holds tasks weakly)
        task.add_done_callback(self._tasks.discard)

    # -- the ROS side (posted from the node's thread) -------------------------------------------------
    def _map_msg(self) -> dict[str, Any]:
        return {
            'map_px': self.map.size,
            'keyframes': [k.to_json() for k in self.map.keyframes()],
            'speed_mps': round(self.speed_mps, 4),
        }

    def on_keyframe(self, stamp: int, t_wc: NDArray[np.float64]) -> None:
        """A keyframe pose: the map, the speed and (the first) every page's start pose."""
        if not self.map.add(stamp, t_wc):
            return
        self.speed_mps = scene_speed([p[:3, 3] for p in self.map.poses.values()],
                                     self.cfg.speed_spacings_per_s, self.cfg.default_speed_mps)  # fmt: skip
        msg = {'type': 'map', **self._map_msg()}
        for c in self.clients:
            if c.session.navigator is not None:
                c.session.navigator.speed_mps = self.speed_mps
            c.send_json(msg)
            self._start(c)

    def on_image(self, stamp: int, jpeg: bytes, rgb: NDArray[np.uint8]) -> None:
        """The view of query ``stamp`` (JPEG-encoded by the node)."""
        if (r := self.replies.get(stamp)) is not None:
            r.jpeg, r.rgb = jpeg, rgb
            self._complete(stamp)

    def on_status(self, stamp: int, status: ReplyStatus) -> None:
        """The status of query ``stamp``."""
        if (r := self.replies.get(stamp)) is not None:
            r.status = status
            self._complete(stamp)

    def _complete(self, stamp: int) -> None:
        r, client = self.replies[stamp], self.owner[stamp]
        if not r.complete:
            return
        st = r.status
        assert st is not None
        query = client.session.in_flight
        if r.jpeg is not None and r.rgb is not None and query is not None and query.stamp == stamp:
            u, v, heading = self.map.project(query.t_wc)
            header = {
                'stamp': str(stamp),  # ns do not fit a JSON number of the page (a double)
                'seq': query.seq,
                'pose': np.round(query.t_wc, 9).tolist(),
                'map': [round(u, 2), round(v, 2), round(heading, 4)],
                'width': int(r.rgb.shape[1]),
                'height': int(r.rgb.shape[0]),
                'result': st.result,
                'valid_fraction': round(st.valid_fraction, 4),
                'render_ms': round(st.render_ms, 1),
                'stats': client.session.stats(),
            }
            shown = _Shown(stamp, r.rgb, query.t_wc)
            if (sent := client.session.frame(stamp, (pack_frame(header, r.jpeg), shown))) is not None:
                client.out.put_nowait(sent[1][0])
                client.last = sent[1][1]
        if not st.published or st.result != 'answered':
            client.send_json({'type': 'status', 'stamp': str(stamp), 'result': st.result,
                              'reason': st.reason, 'message': st.message,
                              'valid_fraction': round(st.valid_fraction, 4)})  # fmt: skip
        if client.timer is not None:
            client.timer.cancel()
            client.timer = None
        # superseded: the renderer took another page's newer query first; ask again at once
        self._finish(client, stamp, st.result, retry=st.reason == 'superseded')
        if st.reason == 'no_model' and client.session.in_flight is None and self._loop is not None:
            # the renderer has not got the model yet: ask again a little later (the page shows why)
            self._loop.call_later(NO_MODEL_RETRY_S, self._retry, client)
