"""Toy deblurring comparison of the restoration-network variants.

Not the paper's data (that is ``restoration/synth*``): a quick, self-made
stand-in to rank design choices of :mod:`restoration.nn.network` on two CPU
cores. Latent images: the Kodak set in ``../shared/data/latent/Kodak24``
(20 for training, 4 for testing), linearised with a 2.2 power. Blur: a
field-dependent anisotropic Gaussian PSF per channel (radial σ grows with
the squared distance to a blur centre, tangential σ less, red wider and
blue narrower than green), applied patch-wise on a 10 × 10 grid (each
patch blurred with its centre's PSF, like the paper's regions). Every
frame is a different "device": blur centre shifted by up to ±0.15 and blur
scaled by 0.6–1.4, so the field position alone does not fix the PSF. Noise:
Gaussian, variance 1e-4 + 2e-3 · signal. Loss: mean squared error in linear
RGB (no pipeline after the slot); PSNR on the test frames in linear RGB.

Run::

    python -m benchmarks.doconv_toy --steps 600          # all variants
    python -m benchmarks.doconv_toy --variants doconv static 'doconv:{"scale": 4, "widths": [64, 128]}'

Prints one line per variant (PSNR, MACs/px, parameters, training time) and,
for the first variant, the tile error against the full frame by overlap;
then one JSON object as its last line with the same figures.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(1)

import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from PIL import Image  # noqa: E402

from restoration.nn.doconv import set_spatial, set_temperature, temperature_schedule  # noqa: E402
from restoration.nn.macs import macs_per_pixel, n_parameters  # noqa: E402
from restoration.nn.network import build_model, forward_padded  # noqa: E402

KODAK = _harness.ROOT.parent / "shared" / "data" / "latent" / "Kodak24"
GRID, KSIZE = 10, 21
CHANNEL_SCALE = (1.15, 1.0, 0.9)


def field_grid(h: int, w: int) -> torch.Tensor:
    """(2, H, W) pixel-centre positions in [-1, 1] (x, y)."""
    ys = (torch.arange(h) + 0.5) / h * 2 - 1
    xs = (torch.arange(w) + 0.5) / w * 2 - 1
    return torch.stack(torch.meshgrid(xs, ys, indexing="xy"))


def psf(x: float, y: float, centre: tuple[float, float], scale: float) -> torch.Tensor:
    """(3, K, K) anisotropic Gaussian PSFs, one per channel, at field (x, y)."""
    dx, dy = x - centre[0], y - centre[1]
    r = math.hypot(dx, dy)
    s_rad = scale * (0.5 + 1.5 * r * r)
    s_tan = scale * (0.5 + 0.5 * r * r)
    ang = math.atan2(dy, dx)
    k = torch.arange(KSIZE, dtype=torch.float32) - KSIZE // 2
    yy, xx = torch.meshgrid(k, k, indexing="ij")
    u = xx * math.cos(ang) + yy * math.sin(ang)
    v = -xx * math.sin(ang) + yy * math.cos(ang)
    out = []
    for c in CHANNEL_SCALE:
        g = torch.exp(-0.5 * ((u / (c * s_rad)) ** 2 + (v / (c * s_tan)) ** 2))
        out.append(g / g.sum())
    return torch.stack(out)


def degrade(img: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """Blur (patch-wise, field-dependent) and noise a (3, H, W) linear image."""
    _, h, w = img.shape
    centre = tuple(rng.uniform(-0.15, 0.15, 2))
    scale = rng.uniform(0.6, 1.4)
    pad = KSIZE // 2
    src = F.pad(img[None], (pad,) * 4, mode="reflect")[0]
    out = torch.empty_like(img)
    ph, pw = h // GRID, w // GRID
    for i in range(GRID):
        for j in range(GRID):
            y0, x0 = i * ph, j * pw
            y1, x1 = (h if i == GRID - 1 else y0 + ph), (w if j == GRID - 1 else x0 + pw)
            cy, cx = (y0 + y1) / h - 1, (x0 + x1) / w - 1
            k = psf(cx, cy, centre, scale)[:, None]
            patch = src[:, y0:y1 + 2 * pad, x0:x1 + 2 * pad][None]
            out[:, y0:y1, x0:x1] = F.conv2d(patch, k, groups=3)[0]
    noise = torch.from_numpy(rng.standard_normal(out.shape).astype(np.float32))
    return out + noise * torch.sqrt(1e-4 + 2e-3 * out.clamp(min=0))


def load(n_devices: int, seed: int = 0):
    """Train and test frames: lists of (input (5, H, W), target (3, H, W))."""
    files = sorted(KODAK.glob("*.png"))
    if len(files) < 24:
        raise SystemExit(f"needs the 24 Kodak images in {KODAK}")
    rng = np.random.default_rng(seed)
    frames = []
    for f in files:
        a = np.asarray(Image.open(f).convert("RGB"), dtype=np.float32) / 255.0
        h, w = (a.shape[0] // 4) * 4, (a.shape[1] // 4) * 4
        lin = torch.from_numpy(a[:h, :w] ** 2.2).permute(2, 0, 1).contiguous()
        fld = field_grid(h, w)
        frames.append([(torch.cat([degrade(lin, rng), fld]), lin) for _ in range(n_devices)])
    train = [p for fr in frames[:20] for p in fr]
    test = [p for fr in frames[20:] for p in fr]
    return train, test


def batches(train, size: int, crop: int, rng: np.random.Generator):
    while True:
        xs, ys = [], []
        for k in rng.integers(len(train), size=size):
            x, y = train[k]
            i = 4 * rng.integers((x.shape[1] - crop) // 4 + 1)
            j = 4 * rng.integers((x.shape[2] - crop) // 4 + 1)
            xs.append(x[:, i:i + crop, j:j + crop])
            ys.append(y[:, i:i + crop, j:j + crop])
        yield torch.stack(xs), torch.stack(ys)


def psnr(model, test) -> float:
    model.eval()
    with torch.no_grad():
        mse = [F.mse_loss(forward_padded(model, x[None][:, :model.in_channels]), y[None]).item() for x, y in test]
    model.train()
    return float(np.mean([10 * math.log10(1 / m) for m in mse]))


def train_one(variant: str, train, test, steps: int, batch: int, crop: int, lr: float, seed: int = 0):
    torch.manual_seed(seed)
    name, _, kw = variant.partition(":")
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in (json.loads(kw) if kw else {}).items()}
    model = build_model(name, **kw)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    data = batches(train, batch, crop, np.random.default_rng(seed))
    t0 = time.perf_counter()
    for step in range(steps):
        set_temperature(model, temperature_schedule(step, steps // 4))
        x, y = next(data)
        loss = F.mse_loss(model(x[:, :model.in_channels]), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    set_temperature(model, 1.0)
    return model, time.perf_counter() - t0


def tile_error(model, x: torch.Tensor, tile: int, overlap: int) -> float:
    """Max |tiled − full| over a frame, tiles of ``tile`` px (multiples of 4)
    with ``overlap`` px of context on each side, outputs cropped to the core."""
    model.eval()
    with torch.no_grad():
        full = forward_padded(model, x[None])[0]
        out = torch.zeros_like(full)
        _, h, w = x.shape
        for i in range(0, h, tile):
            for j in range(0, w, tile):
                y0, x0 = max(i - overlap, 0), max(j - overlap, 0)
                y1, x1 = min(i + tile + overlap, h), min(j + tile + overlap, w)
                t = forward_padded(model, x[None, :, y0:y1, x0:x1])[0]
                out[:, i:i + tile, j:j + tile] = t[:, i - y0:i - y0 + tile, j - x0:j - x0 + tile]
    return float((out - full).abs().max())


def main(argv=None):
    ap = _harness.parser(__doc__)
    ap.add_argument("--variants", nargs="+",
                    default=["doconv", "doconv_spatial_tap", "static", "equal_dilation", "no_field",
                             "doconv_global"])
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--crop", type=int, default=64)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--devices", type=int, default=2, help="degraded versions per latent image")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    _harness.pin_threads(args.threads)
    train, test = load(args.devices)
    base = float(np.mean([10 * math.log10(1 / F.mse_loss(x[:3], y).item()) for x, y in test]))
    print(f"{len(train)} training frames, {len(test)} test frames; input PSNR {base:.2f} dB (linear RGB)")
    print(f"{'variant':24s} {'PSNR dB':>8s} {'kMAC/px':>8s} {'params':>8s} {'train s':>8s}")
    rows, tiles = [], {}
    for k, v in enumerate(args.variants):
        model, secs = train_one(v, train, test, args.steps, args.batch, args.crop, args.lr)
        macs = macs_per_pixel(model) / 1e3
        row = {"variant": v, "psnr_db": round(psnr(model, test), 3), "kmac_per_pixel": round(macs, 2),
               "parameters": n_parameters(model), "train_s": round(secs, 1)}
        print(f"{v:24s} {row['psnr_db']:8.2f} {macs:8.1f} {row['parameters']:8d} {secs:8.0f}", flush=True)
        if model.config["spatial"] == "tap":
            set_spatial(model, "frozen")
            row["psnr_frozen_db"] = round(psnr(model, test), 3)
            print(f"{v + ' → frozen':24s} {row['psnr_frozen_db']:8.2f} {macs:8.1f}", flush=True)
            set_spatial(model, "tap")
        rows.append(row)
        if k == 0:
            x = test[0][0][:model.in_channels]
            for ov in (0, 16, 32, 64, 128):
                tiles[str(ov)] = tile_error(model, x, 128, ov)
                print(f"    tiles 128 px, overlap {ov:3d}: max |tiled − full| = {tiles[str(ov)]:.2e}", flush=True)
    result = {"train_frames": len(train), "test_frames": len(test), "steps": args.steps, "input_psnr_db": round(base, 3),
              "variants": rows, "tile_error_128px_by_overlap": {"variant": args.variants[0], **tiles}}
    return _harness.publish("doconv_toy", result, args, argv)


if __name__ == "__main__":
    main()
