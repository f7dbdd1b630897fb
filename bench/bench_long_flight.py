# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Long flights: ``ibr process`` seconds per keyframe per stage and peak RSS at 100 / 300 / 1000 keyframes.

Runs :func:`ibr_ros.jobs.process.process_bag` on the first N keyframes (``max_keyframes``) of a
synthetic lawnmower flight (``ibr bag synth --trajectory lawnmower --duration 320 --fps 3.5``:
1120 frames at 640x360, 2.3 m apart, so with the default ``config/*.yaml`` every frame is a
keyframe), each size in a fresh subprocess so that its peak RSS (``ru_maxrss``) is its own.
``--make`` writes the bag first (about 4 min on 2 cores).

Printed per size: seconds per keyframe of ``mvs``, ``refine``, ``schedule`` (the refine stage
less MVS and refinement: neighbour search, depth ranges, bookkeeping), ``render`` (the renderer's
model and the ``--views`` novel views), ``write`` (the output bag), ``evaluate`` (previews and
ground truth), ``total``, and the peak RSS in MiB. Flat columns = no cost growing with the flight.

``--overhead``: **MVS stubbed** (each keyframe gets the ground plane z = 0 as its MVS depth, no
sweep): only the costs around MVS are measured, in minutes instead of hours; its ``mvs`` column is
the stub's, not MVS. Without it the real MVS runs (about 1-4 s per keyframe on 2 shared cores).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmark this checkout

REPO = Path(__file__).resolve().parents[1]
COLUMNS = ('mvs', 'refine', 'schedule', 'render', 'write', 'evaluate', 'total')


def make_bag(path: Path) -> None:
    """The lawnmower flight of the module docstring (1120 frames, no labels, little ground truth)."""
    from ibr_ros.jobs.synth_bag import write_synth_bag

    write_synth_bag(path, trajectory='lawnmower', duration_s=320.0, fps=3.5, labels=False, depth_every=1000)


def stub_mvs() -> None:
    """Replace MVS by the ground plane z = 0 seen by the reference view (overhead mode only)."""
    import numpy as np

    import ibr_ros.core.depth.refine as refine
    from ibr_ros.core.depth.mvs import MvsResult

    def plane(views, options=None, depth_range=(0.0, 0.0), **_kw):
        v = views[0]
        rays = v.camera.pixel_rays() @ v.t_wc[:3, :3].T  # world directions, z-depth 1
        with np.errstate(divide='ignore', invalid='ignore'):
            z = -v.t_wc[2, 3] / rays[..., 2]
        depth = np.where(np.isfinite(z) & (z > 0), z, 0.0).astype(np.float32)
        conf = np.where(depth > 0, np.float32(0.9), np.float32(0.0))
        n = np.where(depth > 0, np.uint8(2), np.uint8(0))
        return [MvsResult(depth, conf, n, depth, tuple(range(1, len(views))), '', tuple(depth_range), 0)]

    refine.compute_depth_maps = plane


def one(bag: Path, n: int, views: int, overhead: bool) -> dict[str, object]:
    """``process_bag`` on the first ``n`` keyframes in this process: timings and peak RSS."""
    from ibr_ros.jobs.process import ProcessOptions, process_bag

    if overhead:
        stub_mvs()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        s = process_bag(bag, Path(tmp) / 'out', ProcessOptions(max_keyframes=n, views=views))
        wall = time.perf_counter() - t0
    return {
        'keyframes': s['keyframes'],
        'refined': s['refined'],
        'timings_s': s['timings_s'],
        'wall_s': wall,
        'max_rss_mib': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--bag', type=Path, default=Path(tempfile.gettempdir()) / 'ibr_lawnmower_1120')
    ap.add_argument('--make', action='store_true', help='write the lawnmower bag first')
    ap.add_argument('--sizes', default='100,300,1000', help='keyframe counts (comma separated)')
    ap.add_argument('--views', type=int, default=16, help='novel views (as ibr process)')
    ap.add_argument('--overhead', action='store_true', help='MVS STUBBED: only the costs around MVS')
    ap.add_argument('--one', type=int, help=argparse.SUPPRESS)  # one size, in this process, JSON out
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one(args.bag, args.one, args.views, args.overhead)))
        return 0
    if args.make:
        make_bag(args.bag)
    if not (args.bag / 'synth.json').is_file():
        print(f'{args.bag}: no synthetic bag (pass --make)', file=sys.stderr)
        return 2
    mode = 'OVERHEAD mode: MVS STUBBED (ground plane)' if args.overhead else 'real MVS'
    print(f'ibr process on {args.bag}, {mode}, {args.views} views; seconds per keyframe')
    print(f'{"keyframes":>9} ' + ' '.join(f'{c:>9}' for c in COLUMNS) + f' {"RSS MiB":>8}', flush=True)
    for n in (int(x) for x in args.sizes.split(',')):
        cmd = [sys.executable, __file__, '--bag', str(args.bag), '--one', str(n), '--views', str(args.views)]
        out = subprocess.run(
            cmd + ['--overhead'] * args.overhead, capture_output=True, text=True, check=False
        )
        if out.returncode != 0:
            print(out.stderr[-3000:], file=sys.stderr)
            return 1
        r = json.loads(out.stdout.splitlines()[-1])
        k, t = r['keyframes'], r['timings_s']
        cells = ' '.join(f'{t[c] / k:>9.3f}' for c in COLUMNS)
        print(f'{k:>9} {cells} {r["max_rss_mib"]:>8.0f}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
