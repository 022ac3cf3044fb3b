"""Training of the correction network on synthesised pairs (paper, section 4.2,
eq. 24; ``isp train``).

The loss compares ``Process(Model(J))`` with the sRGB target ``L``:

.. math::

    \\mathcal{L}(θ) = \\frac{1}{N} \\sum_{n=1}^{N}
        \\big\\lVert \\mathrm{Process}_n(\\mathrm{Model}_θ(J_n, φ_n)) - L_n \\big\\rVert_2^2

(mean over pixels and channels; ``l1`` optional). ``Process`` is
:func:`restoration.synth.colour.process_after_slot`: the pipeline's stages
after the correction slot — :func:`modules.luminance.adjust_luminance`,
:func:`modules.ccm.apply_ccm`, :func:`modules.gamma.srgb_oetf` — the same
functions the pipeline runs, here on torch tensors, with each pair's own
colour matrix and exposure (one call per pair of a batch). ``J`` is the
slot's input (camera RGB after demosaic), ``φ`` the field coordinates of
its pixels on the full frame. Adam as in the paper (β₁ = 0.9, β₂ = 0.999,
ε = 10⁻⁸; learning rate halved every 10 epochs); the attention temperature
of the DOConv layers is annealed 30 → 1 (ODConv, DyConv;
:func:`restoration.nn.doconv.temperature_schedule`).

Configuration (TOML or JSON; :mod:`restoration.train.config` reads it)
---------------------------------------------------------------------

Relative paths are taken from the current folder; ``data:PATH`` is
``PATH`` under the shared data folder (``../shared/data`` or ``$ISP_DATA``).

=============================  ===================  ===========================================
key                            default              meaning
=============================  ===================  ===========================================
``data.dirs``                  ``[synth.out]``      ``isp synth`` output folders to train on
``data.crop``                  128                  training crop side, px (multiple of 4)
``data.batch``                 8                    crops per step
``data.val_latents``           4                    latent images held out: their pairs are
                                                    never trained on, validation uses them (0:
                                                    hold out the last ``val_pairs`` pairs)
``data.val_pairs``             32                   validation pairs (0: no validation)
``data.split_seed``            -1                   seed of the held-out draw (-1: ``run.seed``;
                                                    fix it to train a second seed on the same
                                                    split)
``synth.out``                  (required)           where to synthesise pairs when the folder
                                                    has none yet (an existing set is checked
                                                    against this section and reused)
``synth.lens``                 (required)           lens or fitted proxy file
``synth.samples``              1                    1: the lens alone; N: it and N − 1 lenses
                                                    drawn within tolerance
``synth.pairs``                1000                 pairs to synthesise
``synth.size``                 256                  pair side, px
``synth.seed``                 0                    seed of the synthesis
``synth.workers``              2                    processes
``synth.tolerance_scale``      1.0                  scale of the default tolerances
``synth.pixel_um``             0                    the pairs' pixel pitch, µm (the lens
                                                    file's sensor area at it); 0: the file's
``synth.latent``               ``"data:latent"``    latent sRGB images
``synth.cameras``              the two phone DNGs   colour metadata (the first: the sensor)
                               of ``isp synth``
``synth.exposure_ev``          [0, 2]               luminosity compression, EV
``synth.cct_k``                [2850, 7500]         scene white, kelvin
``synth.noise_scale``          [0.5, 2]             factor on the NoiseProfile
``synth.noise``                true                 sensor noise
``synth.blend``                ``"bilinear"``       PSF interpolation between regions
``synth.demosaic``             ``"malvar2004"``     the pipeline's demosaic
``synth.tone``                 ``"none"``           the luminance stage's tone curve
``synth.positions``            ``"frame"``          where crops lie: uniform over the frame, or
                                                    ``"radius"``, uniform in the field radius
``synth.psf_n``                0                    PSF window, half-pixel samples; 0: 32 µm
                                                    (64 on 1 µm pixels)
``synth.psf_grid``             [15, 20]             PSF-map regions (rows, cols)
``synth.shard_size``           100                  pairs per shard
``synth.basis``                ""                   descriptor basis (``isp calib basis``): the
                                                    pairs carry their lens's ``device/v1``
                                                    descriptor, for a conditioned network
``synth.device_components``    16                   descriptor components kept
``data.descriptor_noise``      0                    σ of the noise on each pair's descriptor
                                                    (spread units): the fitted one's error
``data.descriptor_swap``       0                    share of pairs given another pair's
                                                    descriptor (a wrong calibration), in [0, 1)
``model.variant``              ``"doconv"``         :func:`restoration.nn.network.build_model` name
``model.kwargs``               {}                   its overrides, e.g. ``{depths = [1, 2, 1]}``
``model.placement``            ``"pipeline"``       where the model runs and what the loss sees:
                                                    ``"pipeline"``, ``"raw"``, ``"srgb"``,
                                                    ``"linear"``
                                                    (:data:`PLACEMENTS`; the placement ablation)
``optim.loss``                 ``"l2"``             ``"l2"`` (paper, eq. 24) or ``"l1"``
``optim.lr``                   1e-4                 initial learning rate (paper: 1e-4)
``optim.betas``                [0.9, 0.999]         Adam β₁, β₂ (paper)
``optim.eps``                  1e-8                 Adam ε (paper)
``optim.weight_decay``         0.0                  Adam weight decay
``optim.schedule``             ``"step"``           ``"step"``: × ``gamma`` every ``step_epochs``
                                                    epochs (paper: ½ every 10); ``"cosine"``:
                                                    cosine to 0 over ``run.steps``;
                                                    ``"constant"``
``optim.step_epochs``          10.0                 epochs between steps of ``"step"``
``optim.gamma``                0.5                  factor of each step
``optim.warmup_steps``         0                    linear warm-up steps
``optim.grad_clip``            0.0                  max gradient norm (0: off)
``optim.highpass_penalty``     0.0                  weight of the mean square of what the
                                                    residual high-pass removes (the model's
                                                    ``highpass``; :func:`~restoration.nn.network.
                                                    highpass_removed_power`), added to the loss
``temperature.start``          30.0                 attention temperature at step 0
``temperature.end``            1.0                  ... after the annealing (validation and
                                                    :func:`~restoration.nn.checkpoint.load_model`
                                                    use 1: keep it 1)
``temperature.epochs``         10.0                 epochs of linear annealing (ODConv: 10)
``run.steps``                  1000                 optimiser steps in all (``--steps``)
``run.seed``                   0                    model init, split, batches, crops
``run.device``                 ``"auto"``           ``"auto"`` (CUDA when present), ``"cpu"``,
                                                    ``"cuda"``
``run.threads``                2                    torch CPU threads
``run.checkpoint_every``       250                  steps between checkpoints (+ validation)
``run.out``                    ``"out/train"``      output folder (``--out``)
``run.seconds``                0                    wall-clock budget of the steps, s (0: none;
                                                    ``--seconds``): after
                                                    :data:`BUDGET_PROBE` steps the run caps
                                                    ``run.steps`` at what the rest of the budget
                                                    allows at the measured step time (validation
                                                    included), so that the cosine schedule still
                                                    ends at 0; the log records the cap
=============================  ===================  ===========================================

An epoch is one crop from every training pair (``ceil(train pairs /
batch)`` steps).

Output folder
-------------
``checkpoints/step_NNNNNNN.pt`` every ``checkpoint_every`` steps,
``last.pt`` (the latest), ``model.pt`` (the final model; all in the format
of :mod:`restoration.nn.checkpoint`), ``train_log.json`` (config, split,
per-step loss / learning rate / temperature / seconds, validation PSNR)
and ``loss.png``.

Determinism: the model's initialisation comes from ``run.seed``; the batch
of step ``s`` (pairs and crop positions) is a function of ``(seed, s)``
only, the learning rate and temperature of ``s`` too, so a run resumed from
a checkpoint repeats the losses of an uninterrupted one (bit for bit on
the CPU with the same thread count; CUDA kernels are set deterministic).

Crops: the crop's origin on the full frame is a multiple of the network's
``input_multiple`` (4; 8 with ``scale = 4``) where the pair allows, as are the tile origins of the
correction stage at run time (so the CFA phase under the network's
space-to-depth grid is the one it will see). Pairs are held in memory
(``isp synth`` shards: ≈ 0.6 MB per 256² pair).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from isp.errors import ConfigError, InputError

from restoration.train.config import PLACEMENTS, TrainConfig, resolve_path

__all__ = ["PairBank", "batch_plan", "ensure_data", "learning_rate", "process_batch", "split_pairs",
           "split_seed", "synth_argv", "synthesise", "train"]

#: domain and placement of the correction slot the pairs are made for
DOMAIN, PLACEMENT = PLACEMENTS["pipeline"]


def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key)))


# -- data -------------------------------------------------------------------------------

def synth_argv(config: TrainConfig) -> list[str]:
    """The ``isp synth`` arguments of the config's ``[synth]`` section."""
    s = config.synth
    argv = ["--lens", str(resolve_path(s.lens)), "--samples", str(s.samples), "-o", str(resolve_path(s.out)),
            "--pairs", str(s.pairs), "--size", str(s.size), "--seed", str(s.seed), "--workers", str(s.workers),
            "--tolerance-scale", repr(s.tolerance_scale), "--shard-size", str(s.shard_size),
            "--latent", str(resolve_path(s.latent)),
            "--exposure", ",".join(map(str, s.exposure_ev)), "--cct", ",".join(map(str, s.cct_k)),
            "--noise-scale", ",".join(map(str, s.noise_scale)), "--blend", s.blend, "--demosaic", s.demosaic,
            "--tone", s.tone, "--positions", s.positions, "--psf-grid", ",".join(map(str, s.psf_grid))]
    if s.psf_n:
        argv += ["--psf-n", str(s.psf_n)]
    for c in s.cameras:
        argv += ["--camera", str(resolve_path(c))]
    if not s.noise:
        argv.append("--no-noise")
    if s.pixel_um:
        argv += ["--pixel-um", repr(float(s.pixel_um))]
    if s.basis:
        argv += ["--basis", str(resolve_path(s.basis)), "--device-components", str(s.device_components)]
    return argv


def _default_n(psf_map: dict) -> int | None:
    """The default window's samples at a set's PSF-map pitch (None where the
    manifest does not say)."""
    from calibration.optics.psf.map import default_psf_n

    pitch = psf_map.get("pitch_um")
    return default_psf_n(float(pitch)) if pitch else None


def _synth_mismatch(manifest: dict, config: TrainConfig) -> list[str]:
    """Where an existing set differs from the ``[synth]`` section."""
    s = config.synth
    st = manifest.get("settings", {})
    pm = manifest.get("psf_map", {})
    lens = manifest.get("lens", {})
    want = {"pairs": (manifest.get("pairs"), s.pairs), "size": (manifest.get("size"), s.size),
            "seed": (manifest.get("seed"), s.seed), "samples": (lens.get("samples"), s.samples),
            "tolerance_scale": (lens.get("tolerance_scale"), s.tolerance_scale),
            "lens": (Path(str(lens.get("path"))).name, resolve_path(s.lens).name),
            "tone": (st.get("tone"), s.tone), "demosaic": (st.get("demosaic"), s.demosaic),
            "blend": (st.get("blend"), s.blend), "noise": (st.get("noise"), s.noise),
            "positions": (st.get("positions", "frame"), s.positions),
            "exposure_ev": (list(st.get("exposure_ev", [])), list(map(float, s.exposure_ev))),
            "cct_k": (list(st.get("cct_k", [])), list(map(float, s.cct_k))),
            "noise_scale": (list(st.get("noise_scale", [])), list(map(float, s.noise_scale))),
            # a set blurred through another PSF window is another set (the window changed default)
            "psf_n": (pm.get("n"), s.psf_n or _default_n(pm)),
            "psf_grid": (list(pm.get("grid", [])), list(map(int, s.psf_grid)))}
    if s.pixel_um:
        want["pixel_um"] = (pm.get("sensor", {}).get("pixel_pitch_um"), float(s.pixel_um))
    dev = manifest.get("device") or {}
    want["device_components"] = (dev.get("components"), s.device_components if s.basis else None)
    return [f"{k} {have!r} ≠ {need!r}" for k, (have, need) in want.items() if have != need]


def synthesise(config: TrainConfig, *, executor=None, log=print) -> dict:
    """Synthesise the pairs of the config's ``[synth]`` section into
    ``synth.out``, as ``isp synth`` with :func:`synth_argv` would
    (:func:`restoration.synth.pairs.plan`, then
    :func:`~restoration.synth.pairs.generate`), on ``executor`` (an
    :class:`isp.runtime.executor.Executor`; default :func:`synth_executor`).

    Returns
    -------
    dict
        The set's manifest.

    Raises
    ------
    InputError
        The lens file does not exist; ``synth.out`` holds a set already.
    """
    from restoration.synth.defaults import DATA, DEFAULT_CAMERAS
    from restoration.synth.optics import PSF_DEFAULTS
    from restoration.synth.pairs import SynthSettings, generate, plan

    s = config.synth
    lens, out = resolve_path(s.lens), resolve_path(s.out)
    if not lens.exists():
        raise InputError(lens, "no such lens file")
    cameras = [str(resolve_path(c)) for c in s.cameras] or [str(DATA / c) for c in DEFAULT_CAMERAS]
    settings = SynthSettings(size=s.size, exposure_ev=tuple(map(float, s.exposure_ev)),
                             cct_k=tuple(map(float, s.cct_k)), noise_scale=tuple(map(float, s.noise_scale)),
                             noise=s.noise, blend=s.blend, demosaic=s.demosaic, tone=s.tone,
                             positions=s.positions)
    ex = synth_executor(config) if executor is None else executor
    p = plan(str(lens), samples=s.samples, latent_dir=str(resolve_path(s.latent)), cameras=cameras, seed=s.seed,
             settings=settings, tolerance_scale=float(s.tolerance_scale),
             psf_options={"n": s.psf_n or PSF_DEFAULTS["n"], "grid": tuple(int(v) for v in s.psf_grid)},
             pixel_um=float(s.pixel_um) if s.pixel_um else None, executor=ex,
             basis=str(resolve_path(s.basis)) if s.basis else None, device_components=s.device_components)
    m = generate(p, str(out), s.pairs, shard_size=s.shard_size, executor=ex)
    log(f"wrote {m['pairs']} pairs of {m['size']}×{m['size']} in {len(m['shards'])} shards to {out} "
        f"({m['_seconds']:.1f} s; {len(p.maps)} lens{'es' if len(p.maps) > 1 else ''}; "
        f"data sha256 {m['data_sha256'][:16]}…)")
    return m


def synth_executor(config: TrainConfig, *, progress: bool = True):
    """The executor the config's synthesis runs on: ``synth.workers``
    processes (1: in this process), with a progress bar."""
    from isp.runtime.executor import pool_executor

    return pool_executor(config.synth.workers if config.synth is not None else 1, progress=progress)


def ensure_data(config: TrainConfig, *, executor=None, log=print) -> list[Path]:
    """The data folders, synthesised first (:func:`synthesise`, on
    ``executor``: default :func:`synth_executor`) where a ``[synth]``
    section names a folder without a set.

    Raises
    ------
    InputError
        A data folder that is not an ``isp synth`` output.
    ConfigError
        ``synth.out`` holds a set made with other settings.
    """
    from restoration.train.dataset import read_manifest

    dirs = [resolve_path(d) for d in config.data_dirs()]
    if config.synth is not None:
        out = resolve_path(config.synth.out)
        if (out / "manifest.json").is_file():
            bad = _synth_mismatch(read_manifest(out), config)
            if bad:
                raise ConfigError(f"{out} holds a set made with other settings ({'; '.join(bad)}); "
                                  "delete it or change synth.out")
        else:
            ex = synth_executor(config) if executor is None else executor
            argv = synth_argv(config) + ([] if ex.progress else ["--quiet"])
            log("synthesising: isp synth " + " ".join(argv))
            synthesise(config, executor=ex, log=log)
    for d in dirs:
        read_manifest(d)  # InputError naming the folder
    return dirs


def split_seed(config: TrainConfig) -> int:
    """The seed of the held-out draw: ``data.split_seed``, or ``run.seed``
    where it is -1 (the default, as before the key existed)."""
    return config.data.split_seed if config.data.split_seed >= 0 else config.run.seed


def split_pairs(dirs, val_latents: int, val_pairs: int, seed: int):
    """Training and validation pairs of the sets in ``dirs``.

    Held out are all pairs of ``val_latents`` latent images (drawn with
    ``seed`` among those the sets use, identified by SHA-256 across sets):
    none of their pairs is trained on; validation takes the first
    ``val_pairs`` of them. With ``val_latents = 0`` the last ``val_pairs``
    pairs are held out instead.

    Returns
    -------
    train, val : list of (set, pair) int tuples
    held_out : list of str
        The held-out latent files.
    """
    from restoration.train.dataset import read_manifest

    lat, files = [], {}
    for k, d in enumerate(dirs):
        m = read_manifest(d)
        sha = [f["sha256"] for f in m["latent"]["files"]]
        for f in m["latent"]["files"]:
            files.setdefault(f["sha256"], f["path"])
        for s in m["shards"]:
            with np.load(Path(d) / s["file"], allow_pickle=False) as z:
                idx = z["latent"]
            lat += [(k, s["first_index"] + j, sha[int(i)]) for j, i in enumerate(idx)]
    if not lat:
        raise InputError(dirs[0], "the set holds no pairs")
    if val_latents > 0:
        used = sorted({h for _, _, h in lat})
        if val_latents >= len(used):
            raise ConfigError(f"data.val_latents = {val_latents} holds out every latent image "
                              f"(the data uses {len(used)}); lower it")
        held = set(np.asarray(used)[_rng(seed, 5).choice(len(used), val_latents, replace=False)].tolist())
        train = [(k, i) for k, i, h in lat if h not in held]
        val = [(k, i) for k, i, h in lat if h in held][:val_pairs]
        names = sorted(files[h] for h in held)
    else:
        n_val = min(val_pairs, len(lat) - 1)
        train = [(k, i) for k, i, _ in lat[:len(lat) - n_val]]
        val = [(k, i) for k, i, _ in lat[len(lat) - n_val:]] if n_val else []
        names = []
    if not train:
        raise ConfigError("no training pairs left after the validation split")
    return train, val, names


@dataclass
class PairBank:
    """Pairs held in memory (the arrays of :mod:`restoration.synth.shards`).

    Attributes
    ----------
    input : (N, S, S, 3) float16
        Camera RGB after demosaic.
    target : (N, S, S, 3) uint8 or uint16
        sRGB; ``target / target_max``.
    target_max : (N,) float32
    origin : (N, 2) int
        Pair origin (row, col) on the full frame.
    full_size : (N, 2) int
    ccm : (N, 3, 3), exposure_ev : (N,), luma_weights : (N, 3), white : (N,)
    tone : list of str
        ``Process`` settings per pair.
    descriptor : (N, R, C, K) float32 or None
        Each pair's lens descriptor (``device/v1``, from the manifest's
        ``device`` entry; :func:`restoration.synth.pairs.lens_descriptors`),
        None where the sets carry none.
    device : dict or None
        The sets' descriptor basis: ``lens``, ``design``, ``basis``, ``components``.
    """

    input: np.ndarray
    target: np.ndarray
    target_max: np.ndarray
    origin: np.ndarray
    full_size: np.ndarray
    ccm: np.ndarray
    exposure_ev: np.ndarray
    luma_weights: np.ndarray
    white: np.ndarray
    tone: list
    descriptor: np.ndarray | None = None
    device: dict | None = None

    def __len__(self) -> int:
        return len(self.input)

    @property
    def size(self) -> int:
        return int(self.input.shape[1])

    @classmethod
    def load(cls, dirs, pairs) -> PairBank:
        """The ``pairs`` ((set, index) tuples, see :func:`split_pairs`) of the sets in ``dirs``."""
        from restoration.train.dataset import load_shard, read_manifest

        want: dict = {}
        for k, i in pairs:
            want.setdefault(k, set()).add(i)
        cols = {n: [] for n in ("input", "target", "target_max", "origin", "full_size", "ccm", "exposure_ev",
                                "luma_weights", "white", "tone", "descriptor")}
        order, devices = [], set()
        for k, d in enumerate(dirs):
            if k not in want:
                continue
            m = read_manifest(d)
            lum = m["process"]["luminance"]
            dev = m.get("device")
            devices.add(None if dev is None else (dev["lens"], dev["design"], dev["basis"], dev["components"]))
            lens_desc = None if dev is None else np.asarray(dev["descriptors"], np.float32)
            for s in m["shards"]:
                first, n = s["first_index"], s["pairs"]
                rows = [j for j in range(n) if first + j in want[k]]
                if not rows:
                    continue
                z = load_shard(Path(d) / s["file"])
                sizes = {z["input"].shape[1:3], z["target"].shape[1:3]}
                if len(sizes) != 1:
                    raise InputError(Path(d) / s["file"], f"input and target sizes differ: {sorted(sizes)}")
                cols["input"].append(z["input"][rows])
                cols["target"].append(z["target"][rows])
                cols["target_max"].append(np.full(len(rows), float(z["target_max"]), np.float32))
                for key in ("origin", "ccm", "exposure_ev", "luma_weights"):
                    cols[key].append(z[key][rows])
                cols["full_size"].append(np.tile(np.asarray(m["full_size"], np.int64), (len(rows), 1)))
                cols["white"].append(np.full(len(rows), float(lum["white"])))
                cols["tone"] += [lum["tone"]] * len(rows)
                if lens_desc is not None:
                    cols["descriptor"].append(lens_desc[np.asarray(z["lens"])[rows]])
                order += [(k, first + j) for j in rows]
        if not order:
            raise ConfigError("no pairs selected")
        sizes = {a.shape[1:] for a in cols["input"]}
        if len(sizes) != 1:
            raise ConfigError(f"the sets' pairs differ in size ({sorted(sizes)}); train on sets of one size")
        if len(devices) != 1:
            raise ConfigError("the sets differ in their device descriptors (some without, or on other bases): "
                              "train on sets synthesised with one basis, or all without")
        dev = next(iter(devices))
        device = None if dev is None else dict(zip(("lens", "design", "basis", "components"), dev))
        bank = cls(**{k: (v if k == "tone" else np.concatenate(v) if v else None) for k, v in cols.items()},
                     device=device)
        # back to the order asked for (shards are read in file order)
        pos = {p: n for n, p in enumerate(order)}
        perm = np.asarray([pos[tuple(p)] for p in pairs])
        return bank.take(perm)

    def take(self, idx) -> PairBank:
        idx = np.asarray(idx, dtype=np.int64)

        def pick(k, v):
            return v if k == "device" or v is None else [v[i] for i in idx] if k == "tone" else v[idx]

        return PairBank(**{k: pick(k, v) for k, v in vars(self).items()})

    @property
    def channels(self) -> int:
        """Model-input channels of a batch: RGB, field, and the descriptor's."""
        return 5 + (0 if self.descriptor is None else self.descriptor.shape[-1])

    def offsets(self, i: int, crop: int, multiple: int) -> np.ndarray:
        """Crop offsets (per axis) of pair ``i`` that put the crop's origin
        on the full frame on a multiple of ``multiple`` (all offsets if none does)."""
        out = []
        for a in range(2):
            first = int(-self.origin[i, a]) % multiple
            last = self.size - crop
            out.append(np.arange(first, last + 1, multiple) if first <= last else np.arange(0, last + 1))
        return out

    def batch(self, idx, offsets, crop: int, descriptor_noise: float = 0.0, rng=None, descriptor_swap: float = 0.0):
        """Model input ``(B, 5 [+ K], crop, crop)``, target ``(B, 3, crop,
        crop)`` (float32 numpy) and the per-pair ``Process`` metadata. With
        descriptors, channels 5… hold the pair's lens descriptor at each
        pixel (:func:`isp.io.device.descriptor_map`, as the correction stage
        fills them), plus Gaussian noise of ``descriptor_noise`` per region
        and component (a fitted descriptor's own error), drawn from ``rng``;
        with probability ``descriptor_swap`` a pair gets a random pair's
        descriptor instead (a wrong calibration), before the noise."""
        from isp.io.device import descriptor_map
        from modules.correction import field_coordinates

        b = len(idx)
        x = np.empty((b, self.channels, crop, crop), np.float32)
        y = np.empty((b, 3, crop, crop), np.float32)
        for n, (i, (r, c)) in enumerate(zip(idx, offsets)):
            x[n, :3] = self.input[i, r:r + crop, c:c + crop].transpose(2, 0, 1)
            y[n] = self.target[i, r:r + crop, c:c + crop].transpose(2, 0, 1) / self.target_max[i]
            o = (int(self.origin[i, 0]) + r, int(self.origin[i, 1]) + c)
            full = tuple(int(v) for v in self.full_size[i])
            x[n, 3:5] = field_coordinates((crop, crop), o, full)
            if self.descriptor is not None:
                d = self.descriptor[i]
                if descriptor_swap and rng.random() < descriptor_swap:
                    d = self.descriptor[rng.integers(len(self.descriptor))]
                if descriptor_noise:
                    d = d + rng.normal(0.0, descriptor_noise, d.shape)
                x[n, 5:] = descriptor_map(d, np.arange(crop) + o[0], np.arange(crop) + o[1], full)
        return x, y, self.meta(idx)

    def meta(self, idx) -> list[dict]:
        return [{"ccm": self.ccm[i], "exposure_ev": float(self.exposure_ev[i]), "luma_weights": self.luma_weights[i],
                 "tone": self.tone[i], "white": float(self.white[i])} for i in idx]


def batch_plan(step: int, n: int, batch: int, seed: int) -> np.ndarray:
    """Pair indices of ``step``: epochs are permutations of ``0..n-1`` drawn
    from ``(seed, epoch)``, read in consecutive blocks of ``batch``; a pure
    function of ``step`` (so a resumed run draws what the uninterrupted one
    did).

    >>> sorted(np.concatenate([batch_plan(s, 6, 3, 0) for s in (0, 1)]).tolist())
    [0, 1, 2, 3, 4, 5]
    """
    pos = np.arange(step * batch, (step + 1) * batch)
    out = np.empty(batch, np.int64)
    for e in np.unique(pos // n):
        sel = pos // n == e
        out[sel] = _rng(seed, 3, int(e)).permutation(n)[pos[sel] % n]
    return out


def crop_plan(step: int, bank: PairBank, idx, crop: int, multiple: int, seed: int) -> list[tuple[int, int]]:
    """Crop offsets of ``step``'s pairs (a function of ``(seed, step)``)."""
    rng = _rng(seed, 4, step)
    out = []
    for i in idx:
        rows, cols = bank.offsets(int(i), crop, multiple)
        out.append((int(rows[rng.integers(len(rows))]), int(cols[rng.integers(len(cols))])))
    return out


# -- loss ---------------------------------------------------------------------------------

def _per_pair(fn, y, meta: list[dict], **kw):
    """``fn`` (:func:`~restoration.synth.colour.process_after_slot` or its
    inverse) on each pair of a batch ``(B, 3, H, W)`` with its own colour
    matrix, exposure and tone settings."""
    import torch

    return torch.cat([fn(y[n:n + 1], m["ccm"], m["exposure_ev"], luma_weights=m["luma_weights"],
                         tone=m["tone"], white=m["white"], channel_axis=-3, **kw)
                      for n, m in enumerate(meta)])


def process_batch(y, meta: list[dict], gamma: bool = True):
    """``Process`` of the loss on a batch ``(B, 3, H, W)``: the pipeline's
    stages after the slot (:func:`restoration.synth.colour.process_after_slot`,
    i.e. the luminance, ccm and gamma stages' own functions), one call per
    pair with its colour matrix and exposure. Returns sRGB ``(B, 3, H, W)``
    (linear sRGB, before the gamma stage, with ``gamma=False``)."""
    from restoration.synth.colour import process_after_slot

    return _per_pair(process_after_slot, y, meta, gamma=gamma)


def unprocess_batch(y, meta: list[dict]):
    """The inverse of :func:`process_batch`: sRGB ``(B, 3, H, W)`` back to
    the slot's camera RGB, per pair."""
    from restoration.synth.colour import unprocess_after_slot

    return _per_pair(unprocess_after_slot, y, meta)


def model_input(model, x):
    """``x`` (B, 5 [+ K], H, W: RGB, field, descriptor) cut to the channels
    ``model`` takes (3 for a model without field encoding, the ablation
    ``no_field``; 5 for a blind one; the first K' descriptor components for
    one conditioned on K' ≤ K)."""
    n = getattr(model, "in_channels", x.shape[1])
    return x if n == x.shape[1] else x[:, :n]


def predict_srgb(model, x, meta: list[dict], placement: str = "pipeline"):
    """The pipeline's sRGB output with the model at ``placement``: Process(Model(J))
    ("pipeline", "raw"), Model(Process(J)) ("srgb"; the field channels pass
    through) or gamma(Model(Lum+CCM(J))) ("linear")."""
    import torch

    x = model_input(model, x)
    if placement == "srgb":
        return model(torch.cat([process_batch(x[:, :3], meta), x[:, 3:]], dim=1))
    if placement == "linear":
        from modules.gamma import srgb_oetf

        return srgb_oetf(model(torch.cat([process_batch(x[:, :3], meta, gamma=False), x[:, 3:]], dim=1)))
    return process_batch(model(x), meta)


def placed_loss(loss_of, model, x, y, meta: list[dict], placement: str = "pipeline"):
    """The training loss of a model at ``placement`` (:data:`PLACEMENTS`)."""
    if placement == "raw":
        return loss_of(model(model_input(model, x)), unprocess_batch(y, meta))
    return loss_of(predict_srgb(model, x, meta, placement), y)


def loss_fn(name: str):
    import torch.nn.functional as F

    return {"l2": F.mse_loss, "l1": F.l1_loss}[name]


#: steps timed (after 5 of warm-up) before a time budget (``run.seconds``) fixes the step count
BUDGET_PROBE = 50


def budget_steps(step: int, steps: int, left_s: float, step_s: float, checkpoint_s: float,
                 checkpoint_every: int) -> int:
    """The step count a time budget allows (``run.seconds``).

    Parameters
    ----------
    step : int
        Steps done.
    steps : int
        The most the run may take (``run.steps``).
    left_s : float
        Seconds of the budget left.
    step_s, checkpoint_s : float
        Measured seconds per step and per checkpoint (its validation included).
    checkpoint_every : int

    Returns
    -------
    int
        ``min(steps, step + n)``, ``n`` the steps (each with its share of a
        checkpoint) that fit in ``left_s``, at least ``step + 1``.

    Examples
    --------
    >>> budget_steps(55, 10_000, 100.0, 0.05, 1.0, 1000)   # 99 s at 0.051 s per step
    1996
    """
    per_step = step_s + checkpoint_s / checkpoint_every
    n = int(max(left_s - checkpoint_s, 0.0) / per_step) if per_step > 0 else steps
    return int(min(steps, max(step + n, step + 1)))


def learning_rate(config: TrainConfig, step: int, steps_per_epoch: float) -> float:
    """Learning rate of ``step`` (warm-up × schedule; a pure function)."""
    o = config.optim
    lr = o.lr
    if o.warmup_steps and step < o.warmup_steps:
        lr *= (step + 1) / o.warmup_steps
    if o.schedule == "step":
        lr *= o.gamma ** math.floor(step / (o.step_epochs * steps_per_epoch) + 1e-9)
    elif o.schedule == "cosine":
        lr *= 0.5 * (1.0 + math.cos(math.pi * min(step, config.run.steps) / config.run.steps))
    return float(lr)


def temperature(config: TrainConfig, step: int, steps_per_epoch: float) -> float:
    from restoration.nn.doconv import temperature_schedule

    t = config.temperature
    return temperature_schedule(step, round(t.epochs * steps_per_epoch), t.start, t.end)


def psnr_db(a, b) -> float:
    """PSNR of images in [0, 1] (peak 1)."""
    mse = float(((a - b) ** 2).mean())
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)


def validate(model, bank: PairBank, device, multiple: int, placement: str = "pipeline") -> dict:
    """Mean PSNR (dB, sRGB) of ``Process(Model(J))`` and of ``Process(J)``
    (no correction) against the targets, and the mean squared error, on the
    largest square of every validation pair whose origin on the full frame
    is a multiple of ``multiple``."""
    import torch

    if not len(bank):
        return {}
    was = model.training
    model.eval()
    out, base, loss = [], [], []
    try:
        with torch.no_grad():
            for i in range(len(bank)):
                firsts = [int(-bank.origin[i, a]) % multiple for a in range(2)]
                side = (bank.size - max(firsts)) // multiple * multiple
                x, y, meta = bank.batch([i], [tuple(firsts)], side)
                x, y = torch.from_numpy(x).to(device), torch.from_numpy(y).to(device)
                p = predict_srgb(model, x, meta, placement)
                out.append(psnr_db(p, y))
                base.append(psnr_db(process_batch(x[:, :3], meta), y))
                loss.append(float(((p - y) ** 2).mean()))
    finally:
        model.train(was)
    return {"psnr_db": float(np.mean(out)), "input_psnr_db": float(np.mean(base)), "loss": float(np.mean(loss))}


# -- log and plot ------------------------------------------------------------------------

def _write_json(path: Path, obj) -> None:
    from isp.io.files import write_bytes_atomic

    write_bytes_atomic(path, (json.dumps(obj, indent=1) + "\n").encode())


def plot_log(log: dict, path) -> Path:
    """``loss.png``: training loss per step (and its running mean) and
    validation PSNR against the uncorrected input's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = log["history"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    if h["step"]:
        steps, loss = np.asarray(h["step"]), np.asarray(h["loss"])
        a1.plot(steps, loss, lw=0.5, alpha=0.4, label="loss per step")
        w = max(1, min(len(loss) // 10, int(log.get("steps_per_epoch", 1))))
        if w > 1:
            run = np.convolve(loss, np.ones(w) / w, mode="valid")
            a1.plot(steps[w - 1:], run, lw=1.5, label=f"mean of {w} steps")
        a1.set_yscale("log")
        a1.legend()
    a1.set_xlabel("step")
    a1.set_ylabel(f"{log['config']['optim']['loss']} loss on Process(Model(J)) (sRGB)")
    a1.grid(alpha=0.3)
    v = log["val"]
    if v:
        a2.plot([e["step"] for e in v], [e["psnr_db"] for e in v], "o-", label="Process(Model(J))")
        a2.axhline(v[0]["input_psnr_db"], ls="--", c="grey", label="Process(J), uncorrected")
        a2.legend()
    a2.set_xlabel("step")
    a2.set_ylabel("validation PSNR, dB (sRGB)")
    a2.grid(alpha=0.3)
    fig.suptitle(f"{log['model']['variant']} on {log['data'].get('lens', '?')} "
                 f"({log['data']['train_pairs']} training pairs)")
    fig.tight_layout()
    from isp.io.files import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return Path(path)


# -- the loop ----------------------------------------------------------------------------

def _device(name: str):
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("run.device = 'cuda' but no CUDA device is available (use 'auto' or 'cpu')")
    return torch.device(name)


def _old_history(ckpt_path: Path, step: int):
    """History and validation entries up to ``step`` from the ``train_log.json``
    beside a checkpoint (or one folder up)."""
    for d in (ckpt_path.parent, ckpt_path.parent.parent):
        p = d / "train_log.json"
        if p.is_file():
            try:
                old = json.loads(p.read_text())
                h = old["history"]
                keep = [n for n, s in enumerate(h["step"]) if s < step]
                return ({k: [v[n] for n in keep] for k, v in h.items()},
                        [e for e in old.get("val", []) if e["step"] <= step])
            except (ValueError, KeyError, TypeError):
                return None
    return None


def _receptive_radius(model, measure, start: int = 128, largest: int = 512) -> int:
    """:func:`restoration.nn.network.receptive_radius` on the smallest input
    (doubling from ``start``) whose border it does not reach; at ``largest``
    (float64 activations of a 512² input take ~2 GB) a lower bound."""
    size = start
    while True:
        r = measure(model, size=size)
        if r < size // 2 or size >= largest:
            return int(r)
        size *= 2


def train(config: TrainConfig, *, resume=None, executor=None, log=print) -> dict:
    """Train (or resume) as ``config`` says; see the module docstring.

    Parameters
    ----------
    config : TrainConfig
    resume : path, optional
        A checkpoint of an earlier run: weights, optimiser state and step
        are restored and training continues to ``config.run.steps``.
    executor : isp.runtime.executor.Executor, optional
        Runs the synthesis where the config asks for one, and shows the
        progress bars (default :func:`synth_executor`: ``synth.workers``
        processes, with progress). The steps run in this process, on
        ``run.threads`` torch threads.
    log : callable
        Where one-line messages go.

    Returns
    -------
    dict
        The final ``train_log.json`` content (with ``out`` the folder).
    """
    import torch
    from tqdm import tqdm

    from restoration.nn.checkpoint import load_checkpoint, save_checkpoint
    from restoration.nn.doconv import set_temperature
    from restoration.nn.macs import macs_per_pixel, n_parameters
    from restoration.nn.network import build_model, highpass_removed_power, receptive_radius

    r, d = config.run, config.data
    placement = config.model.placement  # checked by TrainConfig
    out = Path(r.out)
    device = _device(r.device)
    torch.set_num_threads(r.threads)
    if device.type == "cuda":
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False

    ckpt = load_checkpoint(resume) if resume is not None else None
    ex = synth_executor(config) if executor is None else executor
    progress = ex.progress
    dirs = ensure_data(config, executor=ex, log=log)
    train_ids, val_ids, held = split_pairs(dirs, d.val_latents, d.val_pairs, split_seed(config))
    t0 = time.perf_counter()
    bank = PairBank.load(dirs, train_ids)
    vbank = PairBank.load(dirs, val_ids) if val_ids else None
    if d.crop > bank.size:
        raise ConfigError(f"data.crop ({d.crop}) is larger than the pairs ({bank.size} px)")
    from restoration.train.dataset import read_manifest

    manifests = [read_manifest(x) for x in dirs]
    log(f"data: {len(bank)} training and {len(val_ids)} validation pairs of {bank.size}² from "
        f"{', '.join(map(str, dirs))} ({time.perf_counter() - t0:.1f} s); held-out latents: {', '.join(held) or '-'}")

    kwargs = dict(config.model.kwargs)
    torch.manual_seed(r.seed)
    model = build_model(config.model.variant, **kwargs)
    ref = build_model(config.model.variant, **kwargs)  # for the measurements, which change a model's mode
    mult = int(model.input_multiple)
    if d.crop % mult:
        raise ConfigError(f"data.crop ({d.crop}) must be a multiple of the model's input multiple ({mult})")
    k_dev = getattr(model, "device", 0)
    if k_dev and (bank.device is None or bank.device["components"] < k_dev):
        have = "no descriptors" if bank.device is None else f"{bank.device['components']} descriptor components"
        raise ConfigError(f"model {config.model.variant} reads {k_dev} device-descriptor channels; the training "
                          f"pairs carry {have} (synthesise with synth.basis and synth.device_components ≥ {k_dev})")
    kmac = macs_per_pixel(ref, (32, 32)) / 1e3
    old_md = (ckpt or {}).get("metadata") or {}
    radius = old_md.get("receptive_radius") or _receptive_radius(ref, receptive_radius)
    del ref
    model.to(device).train()
    o = config.optim
    opt = torch.optim.Adam(model.parameters(), lr=o.lr, betas=tuple(o.betas), eps=o.eps,
                           weight_decay=o.weight_decay)
    spe = len(bank) / d.batch           # steps per epoch (fractional)
    step = 0
    history = {"step": [], "loss": [], "lr": [], "temperature": [], "seconds": []}
    val_log: list = []
    if ckpt is not None:
        if ckpt["variant"] != config.model.variant or ckpt["model_kwargs"] != json.loads(json.dumps(kwargs)):
            raise ConfigError(f"{resume}: checkpoint model {ckpt['variant']} {ckpt['model_kwargs']} differs from "
                              f"the config's {config.model.variant} {kwargs}")
        model.load_state_dict(ckpt["state_dict"])
        if ckpt.get("optimizer") is not None:
            opt.load_state_dict(ckpt["optimizer"])
        step = int(ckpt["step"])
        was = (ckpt.get("metadata") or {}).get("training_data")
        now = ",".join(m["data_sha256"] for m in manifests)
        if was and was != now:
            log(f"note: {resume} was trained on other data (data hash {was[:16]}…); continuing on {now[:16]}…")
        old = _old_history(Path(resume), step)
        if old is not None:
            history, val_log = old
        log(f"resumed from {resume} at step {step}")

    # the file's stem: a patent's lenses share one name (US-12210142-B2-e2, -e9)
    m_lens = manifests[0].get("lens") or {}
    lens = Path(m_lens["path"]).stem if m_lens.get("path") else (m_lens.get("name") or "?")
    metadata = {
        "lens": lens, "fov_encoding": model.fov_encoding, "placement": PLACEMENTS[placement][1],
        "domain": PLACEMENTS[placement][0], "training_placement": placement,
        "training_data": ",".join(m["data_sha256"] for m in manifests), "input_multiple": mult,
        "receptive_radius": radius, "attention": model.config.get("pool", "local"),
        "process": {"stages": ["luminance", "ccm", "gamma"], "tone": bank.tone[0], "white": float(bank.white[0])},
        # provenance, and what lets an evaluation check that its lenses were not trained on (psf_map_key)
        **({"device_components": k_dev, "device_design": bank.device["design"],
            "device_basis": bank.device["basis"]} if k_dev else {}),
        "training_sets": [{"dir": str(x), "data_sha256": m["data_sha256"], "pairs": m["pairs"], "size": m["size"],
                           "seed": m["seed"], "lens": m.get("lens"), "psf_map": m.get("psf_map"),
                           "settings": m.get("settings")} for x, m in zip(dirs, manifests)],
    }
    info = {
        "config": config.to_dict(), "out": str(out), "device": str(device), "threads": r.threads,
        "torch": str(torch.__version__),
        "data": {"dirs": [str(x) for x in dirs], "lens": lens, "training_data": metadata["training_data"],
                 "train_pairs": len(bank), "val_pairs": len(val_ids), "held_out_latents": held,
                 "pair_size": bank.size},
        "model": {"variant": config.model.variant, "kwargs": kwargs, "parameters": n_parameters(model),
                  "kmac_per_pixel": round(kmac, 2), "receptive_radius": radius},
        "steps_per_epoch": spe, "history": history, "val": val_log,
    }
    loss_of = loss_fn(o.loss)
    out.mkdir(parents=True, exist_ok=True)

    def checkpoint(at: int, final: bool = False) -> None:
        # validated as load_model gives it back: at the end temperature (the training loop resets it)
        set_temperature(model, config.temperature.end)
        v = validate(model, vbank, device, mult, placement) if vbank is not None else {}
        if v:
            v = {"step": at, **v}
            if not val_log or val_log[-1]["step"] != at:
                val_log.append(v)
            metadata["val_psnr_db"] = v["psnr_db"]
        kw = {"variant": config.model.variant, "model_kwargs": kwargs, "optimizer": opt, "step": at,
              "epoch": at / spe, "config": info["config"], "metadata": metadata}
        save_checkpoint(out / "checkpoints" / f"step_{at:07d}.pt", model, **kw)
        save_checkpoint(out / "last.pt", model, **kw)
        if final:
            save_checkpoint(out / "model.pt", model, **kw)
        secs = history["seconds"]
        info["seconds_per_step"] = float(np.median(secs)) if secs else None
        _write_json(out / "train_log.json", info)
        plot_log(info, out / "loss.png")
        if v:
            msg = (f"step {at}: validation PSNR {v['psnr_db']:.2f} dB "
                   f"(uncorrected {v['input_psnr_db']:.2f} dB)")
            (tqdm.write if progress else log)(msg)

    if step >= r.steps:
        log(f"nothing to do: the checkpoint is at step {step} ≥ run.steps = {r.steps}")
        checkpoint(step, final=True)
        return info
    t_start = time.perf_counter()
    if not val_log and vbank is not None and step == 0:
        checkpoint(0)   # step 0: the untrained (near-identity) model and the uncorrected input
    t_checkpoint = time.perf_counter() - t_start
    bar = ex.bar(total=r.steps, initial=step, desc="train", unit="step", smoothing=0.05)
    ema = None
    first, t_probe = step, None
    try:
        while step < r.steps:
            t_step = time.perf_counter()
            lr = learning_rate(config, step, spe)
            temp = temperature(config, step, spe)
            for g in opt.param_groups:
                g["lr"] = lr
            set_temperature(model, temp)
            idx = batch_plan(step, len(bank), d.batch, r.seed)
            x, y, meta = bank.batch(idx, crop_plan(step, bank, idx, d.crop, mult, r.seed), d.crop,
                                    d.descriptor_noise, _rng(r.seed, 3, step), d.descriptor_swap)
            x, y = torch.from_numpy(x).to(device), torch.from_numpy(y).to(device)
            loss = placed_loss(loss_of, model, x, y, meta, placement)
            objective = loss + o.highpass_penalty * highpass_removed_power(model) if o.highpass_penalty else loss
            opt.zero_grad(set_to_none=True)
            objective.backward()
            if o.grad_clip:
                torch.nn.utils.clip_grad_norm_(model.parameters(), o.grad_clip)
            opt.step()
            lv = float(loss.detach())
            if not math.isfinite(lv):
                raise ConfigError(f"loss became {lv} at step {step} (lr {lr:.3g}); lower optim.lr or set "
                                  "optim.grad_clip")
            step += 1
            history["step"].append(step - 1)
            history["loss"].append(lv)
            history["lr"].append(lr)
            history["temperature"].append(temp)
            history["seconds"].append(round(time.perf_counter() - t_step, 4))
            ema = lv if ema is None else 0.95 * ema + 0.05 * lv
            bar.set_postfix(loss=f"{ema:.3g}", lr=f"{lr:.2g}", T=f"{temp:.3g}", refresh=False)
            bar.update()
            if r.seconds and step - first == 5:
                t_probe = time.perf_counter()
            elif r.seconds and step - first == 5 + BUDGET_PROBE:
                now = time.perf_counter()
                step_s = (now - t_probe) / BUDGET_PROBE
                cap = budget_steps(step, r.steps, r.seconds - (now - t_start), step_s, t_checkpoint,
                                   r.checkpoint_every)
                config = config.replace("run", steps=cap)
                r = config.run
                info["config"] = config.to_dict()
                info["time_budget"] = {"seconds": r.seconds, "step_s": round(step_s, 5),
                                       "checkpoint_s": round(t_checkpoint, 3), "steps": cap}
                bar.total = cap
                bar.refresh()
                (tqdm.write if progress else log)(f"time budget {r.seconds:g} s: {cap} steps at {step_s:.4f} s/step")
            if r.seconds and time.perf_counter() - t_start > r.seconds:
                break
            if step % r.checkpoint_every == 0 and step < r.steps:
                checkpoint(step)
    except KeyboardInterrupt:
        bar.close()
        checkpoint(step)
        log(f"interrupted: saved {out / 'last.pt'} at step {step}; continue with --resume {out / 'last.pt'}")
        raise
    bar.close()
    checkpoint(step, final=True)
    log(f"wrote {out / 'model.pt'} (step {step}, {len(history['step'])} steps logged, "
        f"median {info['seconds_per_step'] or 0:.3f} s/step on {device}); log and loss.png in {out}")
    return info
