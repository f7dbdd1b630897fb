# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Benchmark: the web viewer's own readout while flying at 640x360, target >= 10 views/s.

Runs ``ibr view --bag`` (bag_player, view_renderer at 640x360, web_viewer, each its own process,
over DDS in a domain of their own) on the 5-keyframe synthetic town of the browser test
(``test/web_model.py``: ``SceneConfig(seed=3)`` orbit frames 24-36, exact depth), opens the page in
headless Debian Chromium (``/usr/bin/chromium`` through Playwright) and flies: W held for
``--leg`` seconds, then S, D, A, E, Q (there and back), for ``--seconds`` in all. Every
0.5 s after the first leg it reads the page's readout (views shown per second over the last 2 s,
median input-to-display latency over the same window) and the renderer's render time from the
view's header. Prints medians of those samples.

Baseline, in this process: ``NovelViewRenderer.render`` of the poses shown (the node's
configuration), median ms; 1000 / that is the rate the renderer alone could give, so the ratio
shows what DDS, JPEG, the socket and the browser cost. Exits 1 when the median rate misses the
target (only warns when the 1-minute load average exceeds the CPU count).
Run: ``.venv/bin/python bench/bench_web_viewer.py``.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # benchmark the checkout, not an installed copy
sys.path.insert(0, str(REPO / 'test'))  # the browser test's model

from web_model import model_views, write_model_bag  # noqa: E402

from ibr_ros.core.render import NovelViewRenderer, output_camera  # noqa: E402
from ibr_ros.node_config import VIEW_RENDERER  # noqa: E402

TARGET_VIEWS_S = 10.0
CHROMIUM = '/usr/bin/chromium'
CHROMIUM_ARGS = [
    '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
    '--disable-component-update', '--disable-sync',
]  # fmt: skip
#: Keys held one leg each: there and back, so the flight stays over the model.
LEGS = ('w', 's', 'd', 'a', 'e', 'q')


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--seconds', type=float, default=24.0, help='flying time (s)')
    p.add_argument('--leg', type=float, default=2.0, help='seconds per key of the pattern')
    p.add_argument('--blend', default='stable', help="the renderer's blend (ibr view's default: stable)")
    a = p.parse_args()
    from playwright.sync_api import sync_playwright

    views = model_views((640, 360))
    print(f'cpus: {os.cpu_count()}, load avg: {os.getloadavg()}')
    with tempfile.TemporaryDirectory(prefix='bench_web_') as tmp:
        bag = write_model_bag(Path(tmp) / 'bag', views)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))
        argv = [sys.executable, '-m', 'ibr_ros.cli.main', 'view', '--bag', str(bag), '--port', '0',
                '--save-dir', str(Path(tmp) / 'saved'), '--logs', str(Path(tmp) / 'logs'),
                '--blend', a.blend]  # fmt: skip
        proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            assert proc.stdout is not None
            url = ''
            for line in proc.stdout:
                if (m := re.search(r'ibr view: open (\S+)', line)) is not None:
                    url = m.group(1)
                    break
            if not url:
                print('ibr view printed no URL', file=sys.stderr)
                return 1
            samples, poses = fly(sync_playwright, url, a.seconds, a.leg, Path(tmp) / 'profile')
        finally:
            proc.send_signal(2)
            proc.wait(timeout=60)
    rates = [s['rate'] for s in samples]
    lats = [s['latency'] for s in samples if s['latency'] is not None]
    render_ms = [s['render_ms'] for s in samples]
    renderer = NovelViewRenderer(views, VIEW_RENDERER.config({'blend': a.blend}).render)
    camera = output_camera(640, 360, 0.0, views[-1].camera)
    renderer.render(poses[0], camera)
    base = []
    for t_wc in poses:
        t0 = time.perf_counter()
        renderer.render(t_wc, camera)
        base.append(1e3 * (time.perf_counter() - t0))
    rate, base_ms = statistics.median(rates), statistics.median(base)
    print(f'{len(samples)} readout samples while flying, 640x360, load avg after: {os.getloadavg()}')
    print(f'  page readout: median {rate:.1f} views/s (min {min(rates):.1f}, max {max(rates):.1f}), '
          f'median latency {statistics.median(lats):.0f} ms')  # fmt: skip
    print(f'  view_renderer render time (status render_ms): median {statistics.median(render_ms):.1f} ms')
    print(f'  baseline, in process: render median {base_ms:.1f} ms = {1e3 / base_ms:.1f} views/s; '
          f'page / renderer-alone rate {rate / (1e3 / base_ms):.2f}')  # fmt: skip
    if rate >= TARGET_VIEWS_S:
        print(f'OK: {rate:.1f} >= {TARGET_VIEWS_S:g} views/s')
        return 0
    loaded = os.getloadavg()[0] > (os.cpu_count() or 1)
    print(f'{"WARNING" if loaded else "FAIL"}: {rate:.1f} < {TARGET_VIEWS_S:g} views/s'
          + (' (machine loaded beyond its cores)' if loaded else ''))  # fmt: skip
    return 0 if loaded else 1


def fly(sync_playwright, url: str, seconds: float, leg: float, profile: Path) -> tuple[list[dict], list]:
    """Fly the page; readout samples and the poses shown."""
    samples: list[dict] = []
    poses: list = []
    with sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS,
            viewport={'width': 960, 'height': 440},
        )  # fmt: skip
        page = ctx.pages[0] if ctx.pages else ctx.new_page()
        page.goto(url)
        page.wait_for_function('window.ibrViewer.frames > 0', timeout=300_000)
        page.focus('#view')
        t_end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < t_end:
            move = LEGS[k % len(LEGS)]
            page.keyboard.down(move)
            leg_end = min(t_end, time.monotonic() + leg)
            while time.monotonic() < leg_end:
                page.wait_for_timeout(500)
                s = page.evaluate(
                    '(s => ({rate: s.rate, latency: s.latency, render_ms: s.header.render_ms, '
                    'pose: s.header.pose}))(window.ibrViewer)'
                )
                if k > 0 or time.monotonic() > leg_end - leg / 2:  # after the ramp-up
                    samples.append(s)
                    poses.append(np.array(s['pose']))
            page.keyboard.up(move)
            k += 1
        print('readout at the end:', page.inner_text('#readout'))
        print('pose panel:', page.inner_text('#pose').replace('\n', '; '))
        ctx.close()
    return samples, poses


if __name__ == '__main__':
    sys.exit(main())
