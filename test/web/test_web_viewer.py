# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""``ibr view --bag`` in a real browser: headless Chromium (Debian's ``/usr/bin/chromium``, driven by
Playwright; nothing is downloaded) against the web_viewer, a view_renderer and a bag_player replaying a
small synthetic 640x360 output bag over DDS.

The page loads and shows a view, W moves the camera forward, the arrows turn it, the view shown is
the renderer's for the pose in its header (the same render in this process, within JPEG error), a
click on the map jumps to that keyframe, the save button writes the view, the readout reports a
rate and a latency (the >= 10 views/s target is checked in bench/bench_web_viewer.py), a
screenshot goes to ``out/web_viewer.png``, and SIGINT stops every node cleanly.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from web_model import model_views, write_model_bag

from ibr_ros.core.render import NovelViewRenderer, output_camera
from ibr_ros.node_config import VIEW_RENDERER

pytestmark = [pytest.mark.dds, pytest.mark.e2e]

CHROMIUM = Path('/usr/bin/chromium')
#: Chromium on a closed network: no background connections (else its sockets get refused), no GPU.
CHROMIUM_ARGS = [
    '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
    '--disable-component-update', '--disable-sync',
]  # fmt: skip


def _browser(playwright, tmp_path: Path):
    """A fresh headless Chromium context (its own profile under ``tmp_path``)."""
    return playwright.chromium.launch_persistent_context(
        str(tmp_path / 'profile'), executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS,
        viewport={'width': 960, 'height': 440},
    )  # fmt: skip


class Viewer:
    """``ibr view --bag`` as a child process; its URL once it printed it."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(
            argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        self.lines: list[str] = []
        self.url_ready = threading.Event()
        self.url = ''
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)
            if (m := re.search(r'ibr view: open (\S+)', line)) is not None:
                self.url = m.group(1)
                self.url_ready.set()
        self.url_ready.set()  # ended without one

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=60)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
            self.thread.join(timeout=5)


def _canvas_rgb(page) -> np.ndarray:
    data = page.evaluate("document.getElementById('view').toDataURL('image/png')")
    png = np.frombuffer(__import__('base64').b64decode(data.split(',', 1)[1]), np.uint8)
    return cv2.cvtColor(cv2.imdecode(png, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _settled(page) -> dict:
    """The header of the view shown once the newest input has been rendered and shown."""
    page.wait_for_function(
        '(s => s.header !== null && s.header.seq === s.seq)(window.ibrViewer)', timeout=60_000
    )
    return page.evaluate('window.ibrViewer.header')


def test_fly_through_an_output_bag_in_chromium(repo, ros_env, python, tmp_path) -> None:
    if not CHROMIUM.is_file():
        pytest.skip(f'no {CHROMIUM} (make test installs the chromium package with apt-get when run as root)')
    sync_api = pytest.importorskip(
        'playwright.sync_api', reason='playwright not installed (requirements/test.txt)'
    )
    views = model_views((640, 360))
    bag = write_model_bag(tmp_path / 'out' / 'bag', views)
    argv = [python, '-m', 'ibr_ros.cli.main', 'view', '--bag', str(bag), '--port', '0',
            '--save-dir', str(tmp_path / 'saved'), '--logs', str(tmp_path / 'logs')]  # fmt: skip
    viewer = Viewer(argv, ros_env)
    try:
        assert viewer.url_ready.wait(120), 'ibr view printed no URL'
        assert viewer.url.startswith('http://127.0.0.1:'), ''.join(viewer.lines)
        with sync_api.sync_playwright() as pw:
            context = _browser(pw, tmp_path)
            page = context.pages[0] if context.pages else context.new_page()
            errors: list[str] = []
            page.on('pageerror', lambda e: errors.append(str(e)))
            page.goto(viewer.url)
            page.wait_for_function('window.ibrViewer.frames > 0', timeout=180_000)  # renderer warm-up
            first = page.evaluate('window.ibrViewer.header')
            first_rgb = _canvas_rgb(page)
            start = np.array(first['pose'])
            np.testing.assert_allclose(start, views[0].t_wc, atol=1e-6)  # starts at the first keyframe

            # W held for 6 views (about 1 m a view at 3 views/s): the camera flies forward along its
            # optical axis, staying over the model; the readout reports the rate.
            page.focus('#view')
            page.keyboard.down('w')
            page.wait_for_function(f'window.ibrViewer.frames >= {first_count(page) + 6}', timeout=120_000)
            readout = page.inner_text('#readout')
            page.keyboard.up('w')
            moved = _settled(page)
            t_wc = np.array(moved['pose'])
            step = t_wc[:3, 3] - start[:3, 3]
            assert step @ start[:3, 2] > 0.5
            assert np.linalg.norm(np.cross(step, start[:3, 2])) < 1e-3  # along the optical axis
            m = re.match(r'([\d.]+) views/s \| latency (\d+) ms \| 640x360', readout)
            assert m is not None, readout
            assert float(m.group(1)) > 0
            assert int(m.group(2)) > 0
            print(f'readout while flying: {readout}')

            # The view shown is the renderer's for that pose, JPEG-encoded at quality 85 by the node:
            # compared with the same encoding of an in-process render, only the browser's decoder
            # differs (the JPEG error itself depends on where the flight stopped).
            shown = _canvas_rgb(page)
            assert shown.shape == (360, 640, 3)
            config = VIEW_RENDERER.config({'blend': 'stable'}).render  # ibr view's blend
            renderer = NovelViewRenderer(views, config)
            out = renderer.render(t_wc, output_camera(640, 360, 0.0, views[-1].camera))
            _, jpeg = cv2.imencode('.jpg', out.rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
            want = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32)
            diff = np.abs(shown.astype(np.float32) - want)
            p99 = np.percentile(diff, 99)
            print(f'shown vs JPEG of the in-process render: mean {diff.mean():.2f}, p99 {p99:.1f}')
            assert diff.mean() < 4.0, diff.mean()  # 0-2.6 here: blocks where the two renders differ
            assert p99 < 40, p99
            assert np.abs(shown.astype(np.float32) - first_rgb).mean() > 3.0  # the view changed

            # The arrows turn the camera about the map's up axis (z) without moving it.
            # Held for 5 input steps of the page (<= 0.25 s each at 60 deg/s: less than 90 deg).
            seq = int(page.evaluate('window.ibrViewer.seq'))
            page.keyboard.down('ArrowLeft')
            page.wait_for_function(f'window.ibrViewer.seq >= {seq + 5}', timeout=60_000)
            page.keyboard.up('ArrowLeft')
            turned = np.array(_settled(page)['pose'])
            np.testing.assert_allclose(turned[:3, 3], t_wc[:3, 3], atol=1e-6)
            assert turned[2, 2] == pytest.approx(t_wc[2, 2], abs=1e-6)  # elevation kept
            a, b = t_wc[:2, 2], turned[:2, 2]
            turn_deg = np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))
            assert 0 < turn_deg < 90  # turned left: counter-clockwise seen from above

            # A click on the map's third keyframe jumps there.
            kf = page.evaluate('window.ibrViewer.keyframes')[2]
            box = page.locator('#map').bounding_box()
            page.mouse.click(box['x'] + kf['u'], box['y'] + kf['v'])
            np.testing.assert_allclose(np.array(_settled(page)['pose']), views[2].t_wc, atol=1e-6)

            # The save button writes the view shown.
            page.click('#save')
            page.wait_for_function('window.ibrViewer.saved !== null', timeout=30_000)
            saved = Path(page.evaluate('window.ibrViewer.saved'))
            png = cv2.imread(str(saved))
            assert png.shape == (360, 640, 3)
            assert saved.with_suffix('.json').is_file()

            (repo / 'out').mkdir(exist_ok=True)
            page.screenshot(path=str(repo / 'out' / 'web_viewer.png'))
            stats = page.evaluate('window.ibrViewer.header.stats')
            assert not errors, errors
            context.close()
        assert stats['answered'] >= 3, stats
        assert stats.get('stale_ack', 0) == 0, stats
    finally:
        code = viewer.stop()
    logs = {p.stem: p.read_text() for p in (tmp_path / 'logs').glob('*.log')}
    assert code == 0, ''.join(viewer.lines)
    for name in ('web_viewer', 'view_renderer', 'bag_player'):
        assert 'shut down by a signal' in logs[name], logs[name][-2000:]
        assert 'Traceback' not in logs[name], logs[name][-2000:]


def first_count(page) -> int:
    return int(page.evaluate('window.ibrViewer.frames'))
