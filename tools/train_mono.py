#!/usr/bin/env python3
# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Train ibr_ros's small monocular depth + sky network on synthetic views and export it to ONNX.

Needs the optional training extra (``pip install -r requirements/train.txt``: torch, CPU build);
the runtime only needs onnxruntime. Stages, all cached in ``--workdir``:

1. render the data set (``data_*.npz``: random towns and views of :mod:`ibr_ros.jobs.mono_data`,
   training seeds only);
2. train (Adam, cosine learning rate) with the MiDaS losses on inverse depth (scale-and-shift
   invariant L1 + multi-scale gradient matching; sky pixels target "farther than everything") and
   binary cross-entropy on the sky logit; a checkpoint every ``--ckpt-every`` steps, ``--resume``
   continues from the last one;
3. export ONNX (opset 17, dynamic H and W, multiples of 32): input ``image`` 1x3xHxW float32 RGB,
   ImageNet-normalised; outputs ``inverse_depth`` 1x1xHxW (relative, larger = nearer) and
   ``sky_logit`` 1x1xHxW (> 0 = sky).

Example (the shipped model)::

    .venv/bin/python tools/train_mono.py --workdir /tmp/ibr_mono_train --out ibr_ros/models/ibr_mono.onnx
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault('NUMBA_NUM_THREADS', '1')  # be gentle with a shared machine

LOG = logging.getLogger('train_mono')
MEAN = np.array([0.485, 0.456, 0.406], np.float32)
STD = np.array([0.229, 0.224, 0.225], np.float32)


def render_dataset(path: Path, n_scenes: int, views: int, size: tuple[int, int]) -> None:
    """Render ``n_scenes * views`` training views to ``path`` (npz: rgb uint8 NxHxWx3, depth float32)."""
    from ibr_ros.jobs.mono_data import TRAIN_SEED_BASE, render_samples

    t0 = time.monotonic()

    def progress(done: int, total: int) -> None:
        if done % 100 == 0 or done == total:
            LOG.info('rendered %d/%d views (%.0f s)', done, total, time.monotonic() - t0)

    seeds = [TRAIN_SEED_BASE + i for i in range(n_scenes)]
    samples = render_samples(seeds, views, size, progress=progress)
    tmp = path.with_suffix('.tmp.npz')
    np.savez(
        tmp,
        rgb=np.stack([s.rgb for s in samples]),
        depth=np.stack([s.depth for s in samples]),
        seed=np.array([s.seed for s in samples]),
    )
    tmp.replace(path)
    LOG.info('data set %s: %d views in %.0f s', path, len(samples), time.monotonic() - t0)


def build_model() -> torch.nn.Module:
    """A small U-Net: 5 stride-2 stages (16..128 channels), global context, one-conv decoder stages to 1/2."""
    import torch
    from torch import nn
    from torch.nn import functional as F  # noqa: N812 - the usual torch alias

    def cbr(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
        )

    class Down(nn.Sequential):
        def __init__(self, cin: int, cout: int) -> None:
            super().__init__(cbr(cin, cout, 2), cbr(cout, cout))

    class Up(nn.Module):
        def __init__(self, cin: int, cskip: int, cout: int) -> None:
            super().__init__()
            self.conv = cbr(cin + cskip, cout)

        def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
            x = F.interpolate(x, size=skip.shape[-2:], mode='bilinear', align_corners=False)
            return self.conv(torch.cat([x, skip], 1))

    class Net(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            ch = (16, 24, 48, 80, 128)
            self.d1 = Down(3, ch[0])  # 1/2
            self.d2 = Down(ch[0], ch[1])  # 1/4
            self.d3 = Down(ch[1], ch[2])  # 1/8
            self.d4 = Down(ch[2], ch[3])  # 1/16
            self.d5 = Down(ch[3], ch[4])  # 1/32
            self.ctx = nn.Sequential(nn.Conv2d(ch[4], ch[4], 1), nn.ReLU(inplace=True))
            self.u4 = Up(ch[4], ch[3], 64)
            self.u3 = Up(64, ch[2], 48)
            self.u2 = Up(48, ch[1], 32)
            self.u1 = Up(32, ch[0], 16)
            self.depth_head = nn.Conv2d(16, 1, 3, 1, 1)
            self.sky_head = nn.Conv2d(16, 1, 3, 1, 1)

        def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            s1 = self.d1(x)
            s2 = self.d2(s1)
            s3 = self.d3(s2)
            s4 = self.d4(s3)
            s5 = self.d5(s4)
            s5 = s5 + self.ctx(s5.mean(dim=(2, 3), keepdim=True))
            y = self.u1(self.u2(self.u3(self.u4(s5, s4), s3), s2), s1)
            size = x.shape[-2:]
            depth = F.interpolate(self.depth_head(y), size=size, mode='bilinear', align_corners=False)
            sky = F.interpolate(self.sky_head(y), size=size, mode='bilinear', align_corners=False)
            return depth, sky

    return Net()


def lr_factor(step: int, steps: int, cycle_steps: int | None = None, decay: float = 0.5) -> float:
    """Learning-rate factor at ``step``: cosine cycles of ``cycle_steps`` (default: one cycle of
    ``steps``; the last cycle ends at ``steps``), each starting with a 200-step warm-up and ``decay``
    times the previous cycle's peak."""
    c = cycle_steps or steps
    k, s = divmod(min(step, steps - 1), c)
    c = min(c, steps - k * c)
    return decay**k * min(1.0, (s + 1) / 200) * 0.5 * (1 + math.cos(math.pi * s / c))


def _normalise(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-image (x - median) / mean|x - median| over ``mask`` (MiDaS); x, mask Bx1xHxW."""
    import torch

    b = x.shape[0]
    xf, mf = x.reshape(b, -1), mask.reshape(b, -1)
    med = torch.stack([xf[i][mf[i]].median() if mf[i].any() else xf.new_zeros(()) for i in range(b)])
    dev = (xf - med[:, None]).abs()
    scale = (dev * mf).sum(1) / mf.sum(1).clamp(min=1)
    return (x - med.view(b, 1, 1, 1)) / scale.clamp(min=1e-6).view(b, 1, 1, 1)


def losses(
    pred_inv: torch.Tensor,
    sky_logit: torch.Tensor,
    gt_inv: torch.Tensor,
    sky: torch.Tensor,
    valid: torch.Tensor,
    *,
    alpha: float = 0.5,
    sky_weight: float = 0.2,
) -> tuple[torch.Tensor, ...]:
    """(total, ssi, gradient, bce) for a batch; all maps Bx1xHxW, ``valid`` = finite non-sky GT."""
    import torch
    from torch.nn import functional as F  # noqa: N812 - the usual torch alias

    p = _normalise(pred_inv, valid)
    t = _normalise(gt_inv, valid)
    # Sky: inverse depth 0, normalised with the same per-image statistics as the scene.
    b = gt_inv.shape[0]
    gf, vf = gt_inv.reshape(b, -1), valid.reshape(b, -1)
    med = torch.stack([gf[i][vf[i]].median() if vf[i].any() else gf.new_zeros(()) for i in range(b)])
    scale = ((gf - med[:, None]).abs() * vf).sum(1) / vf.sum(1).clamp(min=1)
    t_sky = (-med / scale.clamp(min=1e-6)).view(b, 1, 1, 1).expand_as(t)
    t = torch.where(sky, t_sky, t)
    w = valid.float() + sky_weight * sky.float()
    diff = (p - t) * w
    ssi = diff.abs().sum() / w.sum().clamp(min=1)
    grad = pred_inv.new_zeros(())
    r, m = p - t, w
    for _ in range(4):
        gx = (r[..., :, 1:] - r[..., :, :-1]).abs() * m[..., :, 1:] * m[..., :, :-1]
        gy = (r[..., 1:, :] - r[..., :-1, :]).abs() * m[..., 1:, :] * m[..., :-1, :]
        grad = grad + (gx.sum() + gy.sum()) / m.sum().clamp(min=1)
        r, m = r[..., ::2, ::2], m[..., ::2, ::2]
    bce = F.binary_cross_entropy_with_logits(sky_logit, sky.float())
    return ssi + alpha * grad + bce, ssi, grad, bce


def augment(rgb: np.ndarray, depth: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Photometric jitter (gain, gamma, per-channel colour, saturation, grey, noise, blur) and h-flip."""
    import cv2

    x = rgb.astype(np.float32) / 255.0
    if rng.random() < 0.5:
        x, depth = x[:, ::-1], depth[:, ::-1]
    x = x ** float(rng.uniform(0.7, 1.4))
    x = x * rng.uniform(0.85, 1.15, 3).astype(np.float32) * float(rng.uniform(0.7, 1.3))
    grey = x.mean(axis=2, keepdims=True)
    x = grey + (x - grey) * float(rng.uniform(0.4, 1.4))
    if rng.random() < 0.15:
        x = np.repeat(x.mean(axis=2, keepdims=True), 3, axis=2)
    if rng.random() < 0.3:
        x = cv2.GaussianBlur(x, (0, 0), float(rng.uniform(0.3, 1.2)))
    x = x + rng.normal(0, float(rng.uniform(0, 0.03)), x.shape).astype(np.float32)
    x = (np.clip(x, 0, 1) - MEAN) / STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)), np.ascontiguousarray(depth)


def load_real(
    path: Path, views: slice = slice(None), min_pixels: int = 500
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Photos ``views`` with sparse MVS depth (npz of ``tools/real_mvs_data.py``), ``min_pixels`` each."""
    with np.load(path) as z:
        rgb, depth = z['rgb'][views], z['depth'][views]
        pairs = [(r, d) for r, d in zip(rgb, depth, strict=True) if (d > 0).sum() >= min_pixels]
    if not pairs:
        raise SystemExit(f'{path}: no view with {min_pixels} MVS pixels')
    LOG.info('real photos: %d views with MVS depth from %s', len(pairs), path)
    return pairs


def parse_slice(text: str) -> slice:
    """``'a:b'`` (either side may be empty) as a slice; ``''`` = everything."""
    if not text:
        return slice(None)
    a, _, b = text.partition(':')
    return slice(int(a) if a else None, int(b) if b else None)


def real_sample(
    rgb: np.ndarray, depth: np.ndarray, size: tuple[int, int], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """A random crop of the training aspect ratio, resized to ``size`` (depth: nearest, 0 = unknown)."""
    import cv2

    w, h = size
    ih, iw = depth.shape
    cw, ch = min(iw, round(ih * w / h)), min(ih, round(iw * h / w))
    x0, y0 = int(rng.integers(0, iw - cw + 1)), int(rng.integers(0, ih - ch + 1))
    r = cv2.resize(rgb[y0 : y0 + ch, x0 : x0 + cw], (w, h), interpolation=cv2.INTER_AREA)
    d = cv2.resize(depth[y0 : y0 + ch, x0 : x0 + cw], (w, h), interpolation=cv2.INTER_NEAREST)
    return r, d


def export_onnx(model: torch.nn.Module, path: Path, size: tuple[int, int]) -> None:
    """Export ``model`` to ONNX (opset 17, dynamic H/W) and check it against torch on one input."""
    import torch

    model.eval()
    w, h = size
    x = torch.randn(1, 3, h, w)
    tmp = path.with_suffix('.tmp.onnx')
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        model,
        (x,),
        str(tmp),
        input_names=['image'],
        output_names=['inverse_depth', 'sky_logit'],
        dynamic_axes={
            'image': {2: 'height', 3: 'width'},
            'inverse_depth': {2: 'height', 3: 'width'},
            'sky_logit': {2: 'height', 3: 'width'},
        },
        opset_version=17,
        dynamo=False,
    )
    import onnxruntime as ort

    sess = ort.InferenceSession(str(tmp), providers=['CPUExecutionProvider'])
    for ww, hh in ((w, h), (384, 224)):
        xx = torch.randn(1, 3, hh, ww)
        with torch.no_grad():
            ref = model(xx)
        got = sess.run(None, {'image': xx.numpy()})
        err = max(float(np.abs(g - r.numpy()).max()) for g, r in zip(got, ref))
        LOG.info('ONNX vs torch at %dx%d: max abs diff %.2e', ww, hh, err)
        if err > 1e-3:
            raise RuntimeError(f'ONNX export differs from torch by {err}')
    tmp.replace(path)
    LOG.info('wrote %s (%.2f MB)', path, path.stat().st_size / 1e6)


def train(args: argparse.Namespace) -> None:
    """Stages 2 and 3 (see module docstring)."""
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    wd = Path(args.workdir)
    data_path = wd / f'data_{args.scenes}x{args.views}_{args.width}x{args.height}.npz'
    with np.load(data_path) as z:
        rgb_all, depth_all = z['rgb'], z['depth']
    n = len(rgb_all)
    LOG.info('training on %d views of %dx%d', n, args.width, args.height)
    real = load_real(Path(args.real), parse_slice(args.real_views)) if args.real else []
    model = build_model()
    LOG.info('parameters: %d', sum(p.numel() for p in model.parameters()))
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, args.steps, args.cycle_steps))
    step = 0
    ckpt = wd / 'checkpoint.pt'
    if args.resume and ckpt.is_file():
        state = torch.load(ckpt, weights_only=False)
        model.load_state_dict(state['model'])
        opt.load_state_dict(state['opt'])
        sched.load_state_dict(state['sched'])
        step = state['step']
        LOG.info('resumed from %s at step %d', ckpt, step)
    t0, first = time.monotonic(), step
    model.train()
    run = np.zeros(4)
    while step < args.steps:
        rng = np.random.default_rng([args.seed, step])  # data order depends only on seed and step
        idx = rng.choice(n, args.batch, replace=False)
        xs, ds = zip(*(augment(rgb_all[i], depth_all[i], rng) for i in idx))
        x = torch.from_numpy(np.stack(xs))
        d = torch.from_numpy(np.stack(ds))[:, None]
        sky = torch.isinf(d)
        valid = torch.isfinite(d) & (d > 0)
        gt_inv = torch.where(valid, 1.0 / d.clamp(min=1e-3), torch.zeros_like(d))
        pred, logit = model(x)
        total, ssi, grad, bce = losses(pred, logit, gt_inv, sky, valid)
        if real and step >= args.real_from_step:  # sparse MVS supervision: depth terms only, sky unknown
            picks = rng.choice(len(real), args.real_batch, replace=len(real) < args.real_batch)
            xs, ds = zip(
                *(augment(*real_sample(*real[i], (args.width, args.height), rng), rng) for i in picks)
            )
            rd = torch.from_numpy(np.stack(ds))[:, None]
            rvalid = rd > 0
            rpred, rlogit = model(torch.from_numpy(np.stack(xs)))
            r_inv = torch.where(rvalid, 1.0 / rd.clamp(min=1e-3), torch.zeros_like(rd))
            _, rssi, rgrad, _ = losses(rpred, rlogit, r_inv, torch.zeros_like(rvalid), rvalid)
            total = total + args.real_weight * (rssi + 0.5 * rgrad)
        opt.zero_grad()
        total.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
        opt.step()
        sched.step()
        step += 1
        run += [v.item() for v in (total, ssi, grad, bce)]
        if step % args.log_every == 0:
            run /= args.log_every
            LOG.info(
                'step %d/%d loss %.4f (ssi %.4f grad %.4f bce %.4f) lr %.2e %.2f s/step',
                step, args.steps, *run, sched.get_last_lr()[0], (time.monotonic() - t0) / (step - first),
            )  # fmt: skip
            run[:] = 0
        if step % args.ckpt_every == 0 or step == args.steps:
            tmp = ckpt.with_suffix('.tmp')
            torch.save(
                {
                    'model': model.state_dict(),
                    'opt': opt.state_dict(),
                    'sched': sched.state_dict(),
                    'step': step,
                },
                tmp,
            )
            tmp.replace(ckpt)
    LOG.info('training done in %.0f s', time.monotonic() - t0)
    export_onnx(model, Path(args.out), (args.width, args.height))
    meta = {
        'steps': args.steps,
        'cycle_steps': args.cycle_steps,
        'real': args.real,
        'real_from_step': args.real_from_step,
        'real_views': args.real_views,
        'batch': args.batch,
        'views': n,
        'size': [args.width, args.height],
        'seed': args.seed,
        'train_seconds': round(time.monotonic() - t0),
    }
    (wd / 'train_meta.json').write_text(json.dumps(meta, indent=2))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--workdir', required=True, help='cache for the data set, checkpoints and logs')
    p.add_argument('--out', default=str(REPO / 'ibr_ros' / 'models' / 'ibr_mono.onnx'), help='ONNX file')
    p.add_argument('--scenes', type=int, default=240, help='training towns (seeds)')
    p.add_argument('--views', type=int, default=10, help='views per town')
    p.add_argument('--width', type=int, default=256, help='training image width (multiple of 32)')
    p.add_argument('--height', type=int, default=160, help='training image height (multiple of 32)')
    p.add_argument('--steps', type=int, default=11000)
    p.add_argument(
        '--cycle-steps', type=int, default=5500, help='cosine cycle length (warm restarts every cycle)'
    )
    p.add_argument('--batch', type=int, default=8)
    p.add_argument(
        '--real', help='npz of real photos with MVS depth (tools/real_mvs_data.py): sparse supervision'
    )
    p.add_argument('--real-from-step', type=int, default=0, help='use --real from this step on')
    p.add_argument('--real-views', default='', help="views of --real to train on, 'a:b' (default: all)")
    p.add_argument('--real-batch', type=int, default=2, help='real photos per step')
    p.add_argument('--real-weight', type=float, default=0.5, help='weight of the real-photo loss')
    p.add_argument('--lr', type=float, default=2e-3)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--threads', type=int, default=1, help='torch CPU threads')
    p.add_argument('--ckpt-every', type=int, default=200)
    p.add_argument('--log-every', type=int, default=25)
    p.add_argument('--resume', action='store_true', help='continue from workdir/checkpoint.pt')
    p.add_argument('--data-only', action='store_true', help='only render the data set')
    p.add_argument(
        '--export-only', action='store_true', help='export workdir/checkpoint.pt to --out and stop'
    )
    args = p.parse_args(argv)
    if args.width % 32 or args.height % 32:
        p.error('--width and --height must be multiples of 32')
    wd = Path(args.workdir)
    wd.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(
        level=logging.INFO,
        format='%(asctime)s %(message)s',
        handlers=[logging.StreamHandler(), logging.FileHandler(wd / 'train.log')],
    )
    if args.export_only:
        import torch

        torch.set_num_threads(args.threads)
        model = build_model()
        model.load_state_dict(torch.load(wd / 'checkpoint.pt', weights_only=False)['model'])
        export_onnx(model, Path(args.out), (args.width, args.height))
        return 0
    data_path = wd / f'data_{args.scenes}x{args.views}_{args.width}x{args.height}.npz'
    if not data_path.is_file():
        render_dataset(data_path, args.scenes, args.views, (args.width, args.height))
    if not args.data_only:
        train(args)
    return 0


if __name__ == '__main__':
    sys.exit(main())
