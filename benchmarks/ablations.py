"""The restoration ablations of the paper (section 5.4), one table.

Every entry is trained with the same budget on the same synthesised pairs
(the default config's multiple-samples set, ``configs/e9_default.toml``:
the e9 design and two lenses drawn within tolerance), from the same seed,
and evaluated by :func:`restoration.evaluate.rings.evaluate` on the same unseen
proxy cameras (lenses drawn within tolerance from the evaluation's own
seed stream) and the latent images training held out (never trained on by
any entry: one split, one seed), per field ring:

==================  ==========================================================
entry               what changes against "doconv" (ours)
==================  ==========================================================
doconv              the default network, in the pipeline (after demosaic,
                    loss on Process(Model(J)))
static              plain depthwise convs, widths raised to equal MACs
equal_dilation      four kernels, all dilation 1
no_field            no field-position channels
spatial_tap         per-pixel spatial attention, exact (shifted 1×1 convs)
spatial_frozen      spatial attention trained per pixel, frozen to its mean
placement_raw       same position, trained raw → raw (loss in camera RGB)
placement_srgb      at the end of the pipeline, sRGB → sRGB
sqrt_input          ours with the slot input encoded as √x inside the network
static_sqrt         "static" with the √x encoding (against sqrt_input: the
                    dynamic convolution's gain on the √x design)
highpass            sqrt_input with the residual high-pass (``highpass=9``,
                    restoration.nn.network.ResidualHighPass): the packaged design
static_highpass     "static" with √x and the high-pass (against highpass: the
                    dynamic convolution's gain on the packaged design)
srgb_highpass       placement_srgb with the high-pass (against highpass: the
                    placement on the packaged design; linear input, as sRGB
                    is gamma-encoded already)
linear_highpass     highpass with the high-pass on the residual made linear
                    (``highpass_domain="linear"``, with the config's
                    ``optim.highpass_penalty``): the depthwise form of the
                    packaged design
static_linear_hp    "static" with √x and the linear high-pass (against
                    linear_highpass: the dynamic convolution's gain on it)
half_res_blocks     linear_highpass with a block at ½ resolution before and
                    after the ¼-resolution ones (depths 1/4/1; 7.7 kMAC/px)
large               linear_highpass 12× the size (widths 48/192, depths
                    1/6/1; 79 kMAC/px, past the 2-core budget): what
                    capacity buys at 0.9
static_large        static_linear_hp at large's MACs
dense               linear_highpass with dense DOConv kernels on 48
                    channels, three blocks (19.0 kMAC/px): the form that
                    INT8 speeds up (``group_width = 0``)
static_dense        dense static 3×3 convs on 84 channels, dense's MACs
wide_attention      linear_highpass with the attention statistics over 31²
                    px at ¼ resolution (124² at full resolution) instead of
                    7²: can the attention see which blur it corrects?
global_attention    linear_highpass with ODConv's global-mean attention
                    (per crop; not tile-consistent, not exported): the
                    widest statistics there are
pixel_attention     dense with the attention statistics of each pixel
                    alone (``window = 1``): the narrowest, and the packaged
                    design (the 7² box costs INT8 7 % of its time and its
                    tiles 36 px of receptive radius)
linear_srgb_hp      linear_highpass placed between the colour matrix and
                    the gamma (linear sRGB at display exposure; against
                    linear_highpass and srgb_highpass: what the colour
                    matrix and exposure give, without the gamma's)
==================  ==========================================================

The conditioned design (the ``e9_device`` network: the module's 16-number
descriptor per field region as input channels) has entries of its own, each
against ``device``, trained from ``configs/e9_device.toml`` (pairs from 48
lenses, each carrying its descriptor; the recorded run's config was the short
recipe, crops uniform over the frame and the rate halved every 6 epochs):

=====================  =======================================================
entry                  what changes against "device"
=====================  =======================================================
device                 the conditioned network (widths 16, 32, dense
                       DOConv kernels, √x, linear high-pass, 16 descriptor
                       channels), in the pipeline
device_static          dense static 3×3 convs, widths 16, 56 (9.14 against
                       9.16 kMAC/px): is the dynamic convolution worth its
                       name once the device is known?
device_equal_dilation  four kernels, all dilation 1
device_no_field        no field-position channels (the descriptor map still
                       varies over the field, region by region)
device_attention       the DOConv attention driven by field position and
                       descriptor alone, no image content (the issue's form
                       (b): a fixed map per device, foldable for INT8)
device_raw             trained raw → raw (loss in camera RGB)
device_srgb            at the end of the pipeline, sRGB → sRGB (linear input,
                       the gamma-encoded image is its own √x)
=====================  =======================================================

They are trained here with ``--train-only`` and scored as a line runs the
model, by :mod:`benchmarks.device_eval` on the unseen modules of the
packaged model's evaluation, each entry reading the module's quick-fit
``device.json`` (the fits are the packaged model's where its work folder
is kept)::

    python -m benchmarks.ablations --config configs/e9_device.toml --steps 2000 --train-only \
        --out out/abl_device --only device device_static device_equal_dilation device_no_field \
        device_attention device_raw device_srgb
    python -m benchmarks.device_eval --model out/abl_device/device/model.pt \
        --basis modules/models/e9_basis.npz --devices 6 --fit-args '--fine-iter 0' --lights default \
        --label ablations --parts benchmarks/results/device_eval_ablations_parts \
        --work out/device_eval_packaged --extra static=out/abl_device/device_static/model.pt \
        equal_dilation=out/abl_device/device_equal_dilation/model.pt \
        no_field=out/abl_device/device_no_field/model.pt \
        attention=out/abl_device/device_attention/model.pt raw=out/abl_device/device_raw/model.pt \
        srgb=out/abl_device/device_srgb/model.pt

Run (2.3–7 minutes of training per entry at 1,500 steps, 14–16 for the
per-pixel spatial attention, two at a time on the two cores; ten entries
and their evaluation take about 34 minutes on an idle 2-core AMD EPYC)::

    python -m benchmarks.ablations --steps 1500
    python -m benchmarks.ablations --steps 300 --only doconv static   # a quick look

On a GPU machine (``configs/e9_gpu.toml``: nine cameras, 4,000 pairs,
batches of 32; on one H200, 19–25 s of synthesis on 14 processes, then
52–78 ms a step for three entries or two large ones at once)::

    python -m benchmarks.ablations --config configs/e9_gpu.toml --minutes 4 \
        --only linear_highpass static_linear_hp srgb_highpass --workers 3 \
        --psf-workers 14 --train-only --out out/gpu_abl
    # then, anywhere (here: the CPU), the same command without --train-only
    # and with --samples 4: the trained entries are evaluated, not retrained

The dense pair on an H100 (27 s of synthesis, 63.5 ms a step in the
probe, 3,700 steps each)::

    python -m benchmarks.ablations --config configs/e9_gpu.toml --minutes 4 \
        --only dense static_dense --workers 2 --psf-workers 14 --train-only --out out/gpu_abl

``--minutes`` trains every entry 40 steps first, as many at once as the
real run, and sets the steps that fit the slowest into the minutes.

Prints the table and, as its last line, one JSON object: per entry the
PSNR/SSIM per ring (corrected and uncorrected), the validation PSNR at the
end of training, kMAC/px and the training time; it is also written to
``benchmarks/results/ablations.json`` (not by ``--train-only``, which
evaluates nothing). Models and logs go to
``--out`` (default ``out/ablations``); an entry whose ``model.pt`` is there
already is not retrained (``--retrain`` to force).
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from benchmarks import _harness

#: the "large" entries' network: 12x the default's MACs, past the export's
#: 2-core budget (is the gain at 0.9 bound by the network's size?)
LARGE = {"widths": (48, 192), "depths": (1, 6, 1)}
#: the static network of LARGE's MACs (78.9 against 78.7 kMAC/px; the
#: ``static`` factory matches only at the default widths)
STATIC_LARGE = {"widths": (90, 180), "depths": (1, 6, 1)}
#: the "dense" entry's network: linear_highpass with dense DOConv kernels
#: (``group_width = 0``) on 48 channels, three blocks (19.0 kMAC/px, within
#: the export's budget), the form whose convs INT8 speeds up (dense 3×3
#: 2.8× against depthwise 0.74×, ``benchmarks/doconv_speed.py --yardsticks``)
DENSE = {"widths": (16, 48), "depths": (0, 3, 0), "group_width": 0}
#: the static network of DENSE's MACs: dense 3×3 convs on 84 channels (18.8 kMAC/px)
STATIC_DENSE = {"widths": (16, 84), "depths": (0, 3, 0), "group_width": 0}
#: the packaged conditioned network's arguments besides its encoding and high-pass
#: (``configs/e9_device.toml``): the "device" entries depart from it in one respect each
DEVICE = {"widths": (16, 32), "depths": (0, 3, 0), "group_width": 0, "window": 1, "device": 16}
#: the static network of DEVICE's MACs: dense static 3×3 convs, widths 16, 56 (9.14 against 9.16 kMAC/px)
STATIC_DEVICE = {**DEVICE, "widths": (16, 56)}
#: entry → ("variant[:encoding[:highpass[:highpass_domain]]]", placement[, other network arguments])
ENTRIES = {
    "doconv": ("doconv", "pipeline"),
    "static": ("static", "pipeline"),
    "equal_dilation": ("equal_dilation", "pipeline"),
    "no_field": ("no_field", "pipeline"),
    "spatial_tap": ("doconv_spatial_tap", "pipeline"),
    "spatial_frozen": ("doconv_spatial_frozen", "pipeline"),
    "placement_raw": ("doconv", "raw"),
    "placement_srgb": ("doconv", "srgb"),
    "sqrt_input": ("doconv:sqrt", "pipeline"),
    "static_sqrt": ("static:sqrt", "pipeline"),
    "highpass": ("doconv:sqrt:9", "pipeline"),
    "static_highpass": ("static:sqrt:9", "pipeline"),
    "srgb_highpass": ("doconv::9", "srgb"),
    "linear_highpass": ("doconv:sqrt:9:linear", "pipeline"),
    "static_linear_hp": ("static:sqrt:9:linear", "pipeline"),
    "linear_srgb_hp": ("doconv:sqrt:9:linear", "linear"),
    "half_res_blocks": ("doconv:sqrt:9:linear", "pipeline", {"depths": (1, 4, 1)}),
    "large": ("doconv:sqrt:9:linear", "pipeline", LARGE),
    "static_large": ("static:sqrt:9:linear", "pipeline", STATIC_LARGE),
    "dense": ("doconv:sqrt:9:linear", "pipeline", DENSE),
    "static_dense": ("static:sqrt:9:linear", "pipeline", STATIC_DENSE),
    "wide_attention": ("doconv:sqrt:9:linear", "pipeline", {"window": 31}),
    "global_attention": ("doconv:sqrt:9:linear", "pipeline", {"pool": "global"}),
    "pixel_attention": ("doconv:sqrt:9:linear", "pipeline", {**DENSE, "window": 1}),
    "device": ("device:sqrt:9:linear", "pipeline", DEVICE),
    "device_static": ("static:sqrt:9:linear", "pipeline", STATIC_DEVICE),
    "device_equal_dilation": ("device:sqrt:9:linear", "pipeline", {**DEVICE, "dilations": (1, 1, 1, 1)}),
    "device_no_field": ("device:sqrt:9:linear", "pipeline", {**DEVICE, "field": False}),
    "device_attention": ("device_attention:sqrt:9:linear", "pipeline", DEVICE),
    "device_raw": ("device:sqrt:9:linear", "raw", DEVICE),
    "device_srgb": ("device::9", "srgb", DEVICE),
}
RINGS = ("0.1", "0.5", "0.9")
#: steps of the step-time probe of ``--minutes``
PROBE_STEPS = 40


def entry_model(name: str) -> tuple[str, dict, str]:
    """The network variant, its arguments and the placement of entry ``name``.

    >>> entry_model("static_dense")
    ('static', {'encoding': 'sqrt', 'highpass': 9, 'highpass_domain': 'linear', 'widths': (16, 84), \
'depths': (0, 3, 0), 'group_width': 0}, 'pipeline')
    """
    spec, placement, *more = ENTRIES[name]
    variant, enc, highpass, domain = (spec.split(":") + ["", "", ""])[:4]
    kwargs = {**({"encoding": enc} if enc else {}), **({"highpass": int(highpass)} if highpass else {}),
              **({"highpass_domain": domain} if domain else {}), **(more[0] if more else {})}
    return variant, kwargs, placement


def _train(args) -> dict:
    """Train one entry; a failure comes back as ``{"name", "error"}`` so the
    other entries go on."""
    try:
        return _train_one(args)
    except Exception as e:  # noqa: BLE001 — reported per entry, the run continues
        return {"name": args[0], "error": f"{type(e).__name__}: {e}"}


def _train_one(args) -> dict:
    name, config_path, out, steps, seed = args
    _harness.pin_threads(1)   # entries train side by side, one core each
    from restoration.train.trainer import synth_executor, train
    from restoration.train.config import load_config

    variant, kwargs, placement = entry_model(name)
    cfg = load_config(config_path)
    # the kwargs replace the config's own (the default config's high-pass is an entry here, not a baseline)
    cfg = cfg.replace("model", variant=variant, kwargs=kwargs, placement=placement)
    cfg = cfg.replace("run", steps=steps, out=str(out / name), checkpoint_every=steps, threads=1, seed=seed)
    t0 = time.perf_counter()
    info = train(cfg, executor=synth_executor(cfg, progress=False), log=lambda m: None)
    return {"name": name, "seconds": time.perf_counter() - t0,
            "val_psnr_db": (info["val"][-1]["psnr_db"] if info.get("val") else None),
            "val_input_psnr_db": (info["val"][-1]["input_psnr_db"] if info.get("val") else None),
            "kmac_per_pixel": info["model"]["kmac_per_pixel"], "parameters": info["model"]["parameters"],
            "seconds_per_step": info.get("seconds_per_step"), "device": info.get("device")}


def steps_in(minutes: float, seconds_per_step: float, entries: int, workers: int) -> int:
    """Training steps per entry that fit ``minutes`` when ``entries`` train
    ``workers`` at a time at ``seconds_per_step`` each (the slowest's),
    rounded down to 100, at least 100.

    >>> steps_in(4, 0.0516, 3, 3)   # the H200 run of the README
    4600
    >>> steps_in(4, 0.0516, 4, 3)   # a second round halves them
    2300
    """
    rounds = -(-int(entries) // int(workers))
    return max(100, int(minutes * 60 / (seconds_per_step * rounds)) // 100 * 100)


def _steps_for(minutes: float, todo: list, args, out: Path) -> int:
    """The steps that train ``todo`` in about ``minutes``: every entry trains
    :data:`PROBE_STEPS` steps first, as many at once as the real run will
    (so the probe sees what they cost each other on a shared GPU or CPU),
    and the slowest median step sets the count, rounded down to 100."""
    with ProcessPoolExecutor(args.workers) as pool:
        probes = list(pool.map(_train, [(n, args.config, out / "probe", PROBE_STEPS, args.seed) for n in todo]))
    for r in probes:
        if "error" in r:
            raise SystemExit(f"ablations: the probe of {r['name']} failed: {r['error']}")
    slowest = max(probes, key=lambda r: r["seconds_per_step"])
    steps = steps_in(minutes, slowest["seconds_per_step"], len(todo), args.workers)
    print(f"probe ({PROBE_STEPS} steps each, {args.workers} at a time on {slowest['device']}): slowest "
          f"{slowest['name']} {slowest['seconds_per_step'] * 1e3:.1f} ms a step → {steps} steps for "
          f"{minutes:g} min", flush=True)
    return steps


def main(argv=None) -> dict:
    from restoration.synth.defaults import DATA  # ../shared/data, or $ISP_DATA as the training config's data: paths

    ap = _harness.parser(__doc__)
    ap.add_argument("--config", default="configs/e9_default.toml", help="training config (data, optimiser)")
    ap.add_argument("--steps", type=int, default=1500, help="training steps per entry (default 1500)")
    ap.add_argument("--minutes", type=float,
                    help="instead of --steps: as many steps as train the entries in about this many minutes, "
                         f"timed by a {PROBE_STEPS}-step probe of each, run as they will be (out/probe)")
    ap.add_argument("--only", nargs="+", choices=list(ENTRIES), help="a subset of the entries")
    ap.add_argument("--out", default="out/ablations")
    ap.add_argument("--latent", default=str(DATA / "latent"),
                    help="the latent folder training drew from; its held-out images are the test set")
    ap.add_argument("--lens", default=str(DATA / "lenses/phone/US-12210142-B2-e9.zmx"))
    ap.add_argument("--samples", type=int, default=2, help="unseen proxy cameras (default 2)")
    ap.add_argument("--workers", type=int, default=2, help="entries trained at once (default 2)")
    ap.add_argument("--psf-workers", type=int, default=2,
                    help="processes for the unseen proxy cameras' PSF maps (default 2)")
    ap.add_argument("--train-only", action="store_true",
                    help="train, skip the evaluation (e.g. train on a GPU machine, evaluate elsewhere)")
    ap.add_argument("--retrain", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    _harness.pin_threads(2)
    names = args.only or list(ENTRIES)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    todo = [n for n in names if args.retrain or not (out / n / "model.pt").is_file()]
    if todo:
        # the pairs, synthesised once here: entries started at once would each make them
        from restoration.train.trainer import ensure_data
        from restoration.train.config import load_config

        ensure_data(load_config(args.config), log=lambda m: print(m, flush=True))
    trained = {}
    if todo and args.minutes:
        args.steps = _steps_for(args.minutes, todo, args, out)
    if todo:
        print(f"training {len(todo)} entries × {args.steps} steps ({args.workers} at a time): {', '.join(todo)}",
              flush=True)
        with ProcessPoolExecutor(args.workers) as pool:
            for r in pool.map(_train, [(n, args.config, out, args.steps, args.seed) for n in todo]):
                if "error" in r:
                    print(f"  {r['name']}: FAILED, {r['error']}", flush=True)
                    continue
                trained[r["name"]] = r
                (out / r["name"] / "ablation_train.json").write_text(json.dumps(r, indent=1))
                print(f"  {r['name']}: {r['seconds'] / 60:.1f} min, validation {r['val_psnr_db']:.2f} dB "
                      f"(input {r['val_input_psnr_db']:.2f} dB)", flush=True)
    for n in names:
        if n in trained:
            continue
        if (out / n / "ablation_train.json").is_file():
            trained[n] = json.loads((out / n / "ablation_train.json").read_text())
        elif (out / n / "train_log.json").is_file():  # trained by a run that stopped before its summary
            log = json.loads((out / n / "train_log.json").read_text())
            v = log["val"][-1] if log.get("val") else {}
            trained[n] = {"name": n, "val_psnr_db": v.get("psnr_db"), "val_input_psnr_db": v.get("input_psnr_db"),
                          "kmac_per_pixel": log["model"]["kmac_per_pixel"], "parameters": log["model"]["parameters"]}

    if args.train_only:
        return {"steps": args.steps, "entries": trained}
    import tempfile

    from isp.runtime.executor import pool_executor
    from restoration.evaluate.rings import EvalSettings, evaluate

    # the same images for every entry: the latent images training held out
    # (never trained on, by any entry: one split, one seed), linked into one place
    log = json.loads((out / names[0] / "train_log.json").read_text())
    imgs = [Path(args.latent) / h for h in log["data"]["held_out_latents"]]
    names = [n for n in names if (out / n / "model.pt").is_file()]
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for p in imgs:
            os.symlink(p.resolve(), Path(tmp) / f"{p.parent.name}_{p.name}")
        for n in names:
            t0 = time.perf_counter()
            rep = evaluate(out / n / "model.pt", tmp, args.lens,
                           EvalSettings(samples=args.samples, seed=args.seed, baseline="none"), threads=2,
                           executor=pool_executor(args.psf_workers))
            rings = {r: {k: rep["rings"][r][k] for k in ("psnr_uncorrected", "psnr_corrected",
                                                         "ssim_uncorrected", "ssim_corrected")}
                     for r in RINGS}
            results[n] = {"rings": rings, **trained.get(n, {}), "eval_seconds": time.perf_counter() - t0}
            print(f"  evaluated {n}: " + ", ".join(f"{r} {rings[r]['psnr_corrected']:.2f} dB" for r in RINGS),
                  flush=True)

    print()
    print("| entry | kMAC/px | validation | PSNR 0.1 | PSNR 0.5 | PSNR 0.9 | SSIM 0.9 | gain at 0.9 |")
    print("|---|---|---|---|---|---|---|---|")
    for n in names:
        r = results[n]["rings"]
        val = results[n].get("val_psnr_db")
        print(f"| {n} | {results[n].get('kmac_per_pixel', float('nan')):.1f} | "
              + (f"{val:.2f} | " if val is not None else "– | ")
              + " | ".join(f"{r[k]['psnr_corrected']:.2f}" for k in RINGS)
              + f" | {r['0.9']['ssim_corrected']:.4f} | {r['0.9']['psnr_corrected'] - r['0.9']['psnr_uncorrected']:+.2f} dB |")
    r0 = results[names[0]]["rings"]
    print("| uncorrected | – | – | " + " | ".join(f"{r0[k]['psnr_uncorrected']:.2f}" for k in RINGS)
          + f" | {r0['0.9']['ssim_uncorrected']:.4f} | – |")
    summary = {"steps": args.steps, "images": [p.name for p in imgs], "samples": args.samples,
               "config": args.config, "entries": results}
    (out / "ablations.json").write_text(json.dumps(summary, indent=1))
    return _harness.publish("ablations", summary, args, argv)


if __name__ == "__main__":
    main()
