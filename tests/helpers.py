"""Plain functions the tests import: where the shared data lives
(``../shared/data`` beside the repo, or a skip), and the builders of small
synthetic PSF maps, devices and observations. The fixtures that wrap them
are in ``tests/conftest.py``.

Below those, the builders that several test modules of one package share:
the restoration tests' PSF maps, latent images, synthesis plans, TOML
configs and ONNX models; the export tests' model and calibration reader;
the simulated-capture tests' Gaussian PSFs; the lens-file tests' files and
one-line errors; the opcode tests' hand-encoded opcodes. Their fixtures
are in the ``conftest.py`` of the test folder."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
REFERENCE = Path(__file__).resolve().parent / "data" / "reference"
# the sample DNGs in ../shared/data/raw with two calibration illuminants
DUAL_ILLUMINANT_DNGS = ["skia_sample_1mp.dng", "imageio_Blackmagic.dng", "SYNTHETIC_phone_S6meta_512x384.dng"]


def data_file(*parts: str) -> Path:
    """Path of a shared data file; skips the test with the reason if absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not available: {p} (tests that use ../shared/data skip without it)")
    return p


def reference(name: str):
    """A table of published values in ``tests/data/reference`` (its source
    is cited in that folder's README.md): a ``.json`` file as parsed, a
    ``.csv`` file as a list of rows (dicts), numbers as floats."""
    import csv
    import json

    path = REFERENCE / name
    if path.suffix == ".json":
        return json.loads(path.read_text())

    def value(text):
        try:
            return float(text)
        except ValueError:
            return text

    with path.open(newline="") as fh:
        return [{k: value(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def kernel_psf_map(kernel, *, height: int, width: int, grid=(3, 4), n: int = 16, pitch_um: float = 0.5):
    """A PSFMap on a sensor of 1-µm pixels whose PSF in region (r, c),
    channel ch (R, G, B) is ``kernel(r, c, ch, xx, yy)`` on an n×n grid of
    ``pitch_um`` offsets (µm from the centre sample), normalised to sum 1."""
    import numpy as np

    from calibration.optics.lens import Sensor
    from calibration.optics.psf.map import PSFMap, region_centers_mm

    sensor = Sensor(pixel_pitch_um=1.0, width_px=width, height_px=height)
    rows, cols = grid
    o = (np.arange(n) - n // 2) * pitch_um
    xx, yy = np.meshgrid(o, o)
    psfs = np.zeros((rows, cols, 3, n, n))
    for r in range(rows):
        for c in range(cols):
            for ch in range(3):
                g = np.asarray(kernel(r, c, ch, xx, yy), float)
                psfs[r, c, ch] = g / g.sum()
    centers = region_centers_mm(sensor, grid)
    return PSFMap(psfs, pitch_um, centers, np.zeros_like(centers), ("R", "G", "B"), sensor)


def e9_device(names, u, *, grid, noise: float, rng, n: int = 48, pupil_samples: int = 48, n_wavelengths: int = 2):
    """The e9 phone lens and its edges measured on a device perturbed by
    ``u`` (tolerance units) in ``names``: PSF map on ``grid`` (``n``
    samples, ``pupil_samples``, ``n_wavelengths``), an edge pair per
    region with ``noise`` (seeded by ``rng``). Returns (nominal lens,
    observations)."""
    import numpy as np

    from calibration.optics.io import read_lens
    from calibration.fit.proxy import parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.optics.psf.map import PSFMapSettings, psf_map
    from isp.runtime.executor import pool_executor

    lens = read_lens(data_file("lenses", "phone", "US-12210142-B2-e9.zmx"))
    space = parameter_space(lens, names)
    pm = psf_map(space.apply(np.asarray(u, float) * space.tolerance),
                 PSFMapSettings(grid=grid, channels=("G",), n=n, pupil_samples=pupil_samples,
                                n_wavelengths=n_wavelengths), executor=pool_executor(None))
    return lens, synthetic_observations(pm, noise=noise, rng=rng)


def one_site_observations(n: int, meta: dict):
    """``n`` identical observations at one field site (500, 400) px of a
    2000 × 1500 sensor of 2-µm pixels: a green sagittal edge, normal −5°,
    SFRA 0.3 ± 0.002, noise 0.01, step 0.6, a 64 × 96 px ROI, and
    measurement ``meta`` (e.g. ``{"measure": "raw", "cfa": "RGGB"}``)."""
    import numpy as np

    from calibration.fit.observations import FREQ, Observations
    from calibration.optics.lens import Sensor

    sensor = Sensor(pixel_pitch_um=2.0, width_px=2000, height_px=1500)
    return Observations(x_px=np.full(n, 500.0), y_px=np.full(n, 400.0), normal_deg=np.full(n, -5.0),
                        channel=np.array(["G"] * n), orientation=np.array(["sagittal"] * n),
                        sfra=np.full(n, 0.3), sfra_std=np.full(n, 0.002), noise=np.full(n, 0.01),
                        step=np.full(n, 0.6), freq=FREQ, sfr=np.zeros((n, len(FREQ))), sensor=sensor,
                        roi=np.tile([0, 0, 64, 96], (n, 1)), meta=meta)


def make_frame(data, domain=None, **meta):
    """A :class:`isp.Frame` of ``data`` (as float32) in ``domain`` (RAW by
    default) with :class:`isp.CameraMeta` fields ``meta``."""
    import numpy as np

    from isp import CameraMeta, Domain, Frame

    return Frame(np.asarray(data, np.float32), Domain.RAW if domain is None else domain, CameraMeta(**meta))


def canon_meta(**changes):
    """The Canon EOS 5D Mark II profile printed in colour-hdri's
    documentation (``reference("colour_hdri_canon_eos_5d_mark_ii.json")``)
    as :class:`isp.meta.CameraMeta`: ColorMatrix1/2 for illuminants A and
    D65, the same ForwardMatrix for both, and its AsShotNeutral; ``changes``
    replace fields."""
    import numpy as np

    from isp.meta import CameraMeta

    ref = reference("colour_hdri_canon_eos_5d_mark_ii.json")
    fm = np.array(ref["forward_matrix"])
    kw = dict(color_matrix_1=np.array(ref["color_matrix_1"]), color_matrix_2=np.array(ref["color_matrix_2"]),
              forward_matrix_1=fm, forward_matrix_2=fm.copy(),
              calibration_illuminant_1=ref["calibration_illuminant_1"],
              calibration_illuminant_2=ref["calibration_illuminant_2"],
              as_shot_neutral=tuple(ref["as_shot_neutral"]))
    kw.update(changes)
    return CameraMeta(**kw)


# DNG colour tags (DNG 1.7.1.0, chapter 4) → CameraMeta field and shape
_COLOUR_TAGS = {
    50721: ("color_matrix_1", "matrix"), 50722: ("color_matrix_2", "matrix"),
    50723: ("camera_calibration_1", "matrix"), 50724: ("camera_calibration_2", "matrix"),
    50964: ("forward_matrix_1", "matrix"), 50965: ("forward_matrix_2", "matrix"),
    50727: ("analog_balance", "vector"), 50728: ("as_shot_neutral", "vector"),
    50729: ("as_shot_white_xy", "vector"),
    50778: ("calibration_illuminant_1", "int"), 50779: ("calibration_illuminant_2", "int"),
}


def dng_colour_meta(name: str):
    """The colour tags of ``../shared/data/raw/NAME`` read by tifffile, an
    independent reader of the project's (IFD0 only), as
    :class:`isp.meta.CameraMeta`; skips without the shared data or
    tifffile."""
    import numpy as np

    from isp.meta import CameraMeta

    path = data_file("raw", name)
    tifffile = pytest.importorskip("tifffile")

    def rationals(value):
        v = np.asarray(value, dtype=np.float64).reshape(-1)   # tifffile: flat (num, den, num, den, ...)
        return v[0::2] / v[1::2]

    kw = {}
    with tifffile.TiffFile(path) as tif:
        for tag in tif.pages[0].tags.values():   # the colour tags sit in IFD0 for these files
            if tag.code in _COLOUR_TAGS and _COLOUR_TAGS[tag.code][0] not in kw:
                field, kind = _COLOUR_TAGS[tag.code]
                if kind == "matrix":
                    kw[field] = rationals(tag.value).reshape(3, 3)
                elif kind == "vector":
                    kw[field] = tuple(rationals(tag.value))
                else:
                    kw[field] = int(tag.value)
    return CameraMeta(path=str(path), **kw)


def one_surface(c=0.0, k=0.0, asphere=(), n=1.5, t=10.0, sd=None, epd=2.0):
    """A single refracting surface (the stop) of curvature ``c`` (1/mm),
    conic ``k`` and aspheric terms ``asphere``, into glass of constant index
    ``n``, ``t`` mm before the image; semi-diameter ``sd`` mm, entrance
    pupil ``epd`` mm."""
    import math

    from calibration.optics.lens import Lens, Surface
    from calibration.optics.materials import Material

    m = Material(f"{n}", n, math.inf, "constant")
    return Lens((Surface(c, k, tuple(asphere), t, m, sd, stop=True),), epd=epd)


def small_lens(last=None):
    """A two-singlet aspheric lens with a front stop (EPD 1 mm, 20° half
    field), focused paraxially, or with the last thickness ``last`` mm."""
    from calibration.optics import paraxial
    from calibration.optics.lens import Lens, Surface
    from calibration.optics.materials import Material

    g1 = Material("1.544/55.9", 1.544, 55.9)
    g2 = Material("1.639/23.5", 1.639, 23.5)
    s = (Surface(0.0, thickness=0.1, semi_diameter=0.6, stop=True),
         Surface(0.5, -1.0, ((4, -0.01),), 0.8, g1, 1.0),
         Surface(-0.2, 0.0, (), 0.4, semi_diameter=1.1),
         Surface(0.3, 0.0, ((4, -0.02), (6, 0.003)), 0.5, g2, 1.2),
         Surface(0.25, 0.0, (), 2.0, semi_diameter=1.3))
    lens = Lens(s, epd=1.0, half_fov_deg=20.0)
    bfl = paraxial.first_order(lens).bfl if last is None else last
    return lens.with_surface(4, thickness=bfl)


# -- the network, evaluation, synthesis and training tests (restoration) ------------

def randomise_attention(layer, std=0.5, seed=0):
    """Attention weights of a DOConv ``layer`` far from their near-uniform
    initialisation, so the attentions differ between images, pixels and
    kernels."""
    import torch

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in layer.attention.parameters():
            p.copy_(torch.randn(p.shape, generator=g, dtype=p.dtype) * std)


#: the frame (height, width) the evaluation tests' PSF maps and crops are on
EVAL_FRAME = (384, 512)


def ring_psf_map(kind="gauss", shift=(0, 0), grid=(3, 4), n=32, pitch_um=0.5):
    """A PSFMap on the :data:`EVAL_FRAME` sensor of 1-µm pixels: Gaussians
    widening with the field radius (σ 0.3 px at the centre to ≈ 1.8 px in
    the corners, per channel a little wider), or deltas displaced by
    ``shift`` PSF samples (``pitch_um`` µm on 1-µm pixels)."""
    import math

    import numpy as np

    rows, cols = grid

    def kernel(r, c, ch, xx, yy):
        if kind == "delta":
            k = np.zeros_like(xx)
            k[n // 2 + shift[0], n // 2 + shift[1]] = 1.0
            return k
        rho = math.hypot((r + 0.5) / rows - 0.5, (c + 0.5) / cols - 0.5) / math.hypot(0.5, 0.5)
        s = 0.3 + 1.5 * rho + 0.1 * ch
        return np.exp(-(xx ** 2 + yy ** 2) / (2 * s * s))

    h, w = EVAL_FRAME
    return kernel_psf_map(kernel, height=h, width=w, grid=grid, n=n, pitch_um=pitch_um)


def identity_model(J, origin, full_size):
    """A correction model (the evaluation's runner signature) that returns
    its input."""
    return J


def onnx_select_rgb(path, meta=None):
    """An ONNX model whose output is its input's RGB (a 1×1 conv selecting
    channels 0–2 of RGB + field), with the correction stage's metadata;
    written to ``path``, which it returns (a skip without onnx)."""
    import numpy as np

    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    w = np.zeros((3, 5, 1, 1), np.float32)
    w[[0, 1, 2], [0, 1, 2]] = 1.0
    inp = helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 5, "h", "w"])
    out = helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, 3, "h", "w"])
    graph = helper.make_graph([helper.make_node("Conv", ["input", "w"], ["output"])], "sel", [inp], [out],
                              initializer=[helper.make_tensor("w", TensorProto.FLOAT, w.shape, w.ravel())])
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    for k, v in {"domain": "camera_rgb", "fov_encoding": "xy", "input_multiple": "4", "lens": "toy",
                 **(meta or {})}.items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


def field_gaussian_map(height=96, width=128, grid=(3, 4), n=16, pitch_um=0.5, sigmas=None, delta=False):
    """A PSF map of Gaussians whose width grows over the field (and differs
    per channel; ``sigmas[r, c, ch]`` in PSF samples where given), or of
    deltas (an ideal lens)."""
    import numpy as np

    def kernel(r, c, ch, xx, yy):
        if delta:
            return (xx == 0) & (yy == 0)
        s = sigmas[r, c, ch] if sigmas is not None else 0.4 + 0.35 * (r + c) + 0.15 * ch
        return np.exp(-((xx - 0.2 * c) ** 2 + (yy - 0.1 * r) ** 2) / (2 * s * s))

    return kernel_psf_map(kernel, height=height, width=width, grid=grid, n=n, pitch_um=pitch_um)


def latent_png(tmp_path, size=96, seed=0):
    """A latent sRGB image with edges and texture (8-bit PNG) in
    ``tmp_path / "latent"``; returns that folder."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size]
    img = np.stack([0.5 + 0.4 * np.sin(x / 6.0 + k) * np.cos(y / 9.0 - k) for k in range(3)], -1)
    img[size // 3:2 * size // 3, size // 4:size // 2] = rng.uniform(0.05, 0.95, 3)
    u8 = np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)
    d = tmp_path / "latent"
    d.mkdir(exist_ok=True)
    cv2.imwrite(str(d / f"img{seed}.png"), u8[:, :, ::-1])
    return d


def make_synth_plan(tmp_path, cameras, maps, *, seed=0, **settings):
    """A :class:`restoration.synth.pairs.SynthPlan` of 32-px pairs from
    ``maps`` (``None``: an ideal lens), ``cameras`` and one
    :func:`latent_png`; ``settings`` replace :class:`SynthSettings` fields."""
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents
    from restoration.synth.colour import colour_table

    st = SynthSettings(**{"size": 32, "cct_steps": 4, **settings})
    m0 = next((m for m in maps if m is not None), None)
    full = (m0.sensor.height_px, m0.sensor.width_px) if m0 is not None else (96, 128)
    lat = tuple(str(p) for p in find_latents(latent_png(tmp_path)))
    return SynthPlan(tuple(maps), cameras, colour_table(list(cameras), st.cct_k, st.cct_steps), lat, full,
                     seed, st, (4e-4, 1e-6))


def widening_gaussian_map(height=96, width=128, grid=(3, 4), n=16, pitch_um=0.5):
    """Gaussian PSFs whose width grows over the field (a known blur)."""
    import numpy as np

    def kernel(r, c, ch, xx, yy):
        s = 0.6 + 0.4 * (r + c) + 0.15 * ch
        return np.exp(-(xx ** 2 + yy ** 2) / (2 * s * s))

    return kernel_psf_map(kernel, height=height, width=width, grid=grid, n=n, pitch_um=pitch_um)


def latent_pngs(d, size=144, count=3):
    """``count`` latent sRGB images with edges and texture (8-bit PNG) in
    the folder ``d`` (made if absent); returns ``d``."""
    import cv2
    import numpy as np

    d.mkdir(parents=True, exist_ok=True)
    for seed in range(count):
        rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:size, 0:size]
        img = np.stack([0.5 + 0.4 * np.sin(x / (3.0 + seed) + k) * np.cos(y / 5.0 - k) for k in range(3)], -1)
        for _ in range(6):
            r, c, h, w = rng.integers(0, size - 20, 4) // 1
            img[r:r + 8 + h % 24, c:c + 8 + w % 24] = rng.uniform(0.05, 0.95, 3)
        u8 = np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)
        cv2.imwrite(str(d / f"img{seed}.png"), u8[:, :, ::-1])
    return d


#: the model arguments of the tiny DOConv UNet the training and checkpoint tests build
TINY_UNET_KW = {"widths": [8, 16], "depths": [1, 1, 1], "expansion": 2}


def write_toml(path, d: dict):
    """Write the two-level dict ``d`` (sections of keys) as TOML to ``path``;
    returns ``path``."""
    import json

    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    path.write_text("".join(f"[{s}]\n" + "".join(f"{k} = {val(v)}\n" for k, v in t.items()) + "\n"
                            for s, t in d.items()))
    return path


# -- the export tests ------------------------------------------------------------------

#: the model arguments of the tiny DOConv UNet the export tests export
EXPORT_KW = {"widths": [8, 16], "depths": [1, 1, 1]}
#: the checkpoint metadata the export tests export with
EXPORT_META = {"domain": "camera_rgb", "placement": "camera_rgb after demosaic", "lens": "test-lens",
               "fov_encoding": "xy", "training_data": "abc123", "input_multiple": 4, "receptive_radius": 63,
               "attention": "local", "process": {"tone": "none", "white": 4.0}}


def onnx_calibration_reader(n=6, size=64, seed=0, device=0):
    """Calibration crops (1, 5 [+ device], size, size): smooth random RGB +
    field (+ a random device descriptor's channels)."""
    from export.onnx_export import model_input, sample_frame

    class Reader:
        def __init__(self):
            self.it = iter([{"input": model_input(sample_frame((size, size), True, seed + k), True, device, seed + k)}
                            for k in range(n)])

        def get_next(self):
            return next(self.it, None)

        def __len__(self):
            return n

    return Reader()


# -- the simulated-capture tests (calibration.simulate, calibration.optics.illumination) --

def gaussian_psf(sigma_um: float, pitch_um: float, n: int = 65, *, sigma_y_um: float | None = None,
                 theta_deg: float = 0.0, shift_um=(0.0, 0.0)):
    """(n, n) samples of a (rotated, elliptical, shifted) Gaussian, summing
    to 1, in the calibration.optics.psf.result grid convention (centre n//2)."""
    import math

    import numpy as np

    o = (np.arange(n) - n // 2) * pitch_um
    x, y = np.meshgrid(o - shift_um[0], o - shift_um[1])
    t = math.radians(theta_deg)
    u, v = x * math.cos(t) + y * math.sin(t), -x * math.sin(t) + y * math.cos(t)
    sy = sigma_um if sigma_y_um is None else sigma_y_um
    g = np.exp(-0.5 * (u * u / sigma_um ** 2 + v * v / sy ** 2))
    return g / g.sum()


def gaussian_psf_map(sensor, grid, sigma_um, pitch_um: float | None = None, n: int = 49):
    """A PSFMap of Gaussians on ``sensor`` (a :class:`calibration.optics.lens.Sensor`);
    ``sigma_um(row, col, channel)`` → σ in µm."""
    import numpy as np

    from calibration.optics.psf.map import PSFMap, region_centers_mm

    pitch = sensor.pixel_pitch_um / 4 if pitch_um is None else pitch_um
    rows, cols = grid
    ps = np.empty((rows, cols, 3, n, n), np.float32)
    for r in range(rows):
        for c in range(cols):
            for k in range(3):
                ps[r, c, k] = gaussian_psf(sigma_um(r, c, k), pitch, n)
    return PSFMap(ps, pitch, region_centers_mm(sensor, grid), np.zeros((rows, cols, 2)), ("R", "G", "B"), sensor)


def smooth_ri(sensor, corner: float = 0.36):
    """A smooth phone-like relative illumination on ``sensor``, ``corner``
    at the sensor's corner."""
    import numpy as np

    from calibration.optics.illumination import RelativeIllumination

    hd = sensor.half_diagonal_mm
    r = np.linspace(0.0, 1.05 * hd, 24)
    return RelativeIllumination.from_samples(r, 1.0 - (1.0 - corner) * (r / hd) ** 2)


# -- the lens-file tests (calibration.optics.io) ----------------------------------------

def write_lens_file(tmp_path, name, text, encoding="utf-8"):
    """``text`` written to ``tmp_path / name`` in ``encoding``; returns the path."""
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


def one_line_lens_error(fn, *args, **kw) -> str:
    """The message of the LensError ``fn`` raises; asserts it is one line."""
    from calibration.optics.lens import LensError

    with pytest.raises(LensError) as e:
        fn(*args, **kw)
    msg = str(e.value)
    assert "\n" not in msg and msg, msg
    return msg


def minimal_lens_dict(**over) -> dict:
    """A minimal lens/v1 singlet (surfaces, aperture) as a dict; ``over``
    replaces top-level keys."""
    d = {"schema": "lens/v1",
         "surfaces": [{"radius": 50.0, "thickness": 4.0, "material": "N-BK7", "semi_diameter": 6.0},
                      {"radius": "inf", "thickness": 1.0, "stop": True, "semi_diameter": 5.0},
                      {"curvature": -0.02, "thickness": 45.0}],
         "aperture": {"epd": 10.0}}
    d.update(over)
    return d


# -- the opcode tests (isp.opcodes): shared blobs and opcodes encoded by hand (DNG 1.7.1.0, ch. 7) --

def raw_data_file(*parts) -> Path:
    """Path of a file in ``../shared/data/raw``, or a skip."""
    return data_file("raw", *parts)


def opcode_blob(name: str) -> bytes:
    """The bytes of the sample opcode list ``../shared/data/raw/opcodes/NAME`` (or a skip)."""
    return raw_data_file("opcodes", name).read_bytes()


def tiff_tag(path: Path, subifd: bool, name: str = "OpcodeList2") -> bytes:
    """The value of TIFF tag ``name`` of IFD0 (or its first SubIFD), read by
    tifffile (a skip without it)."""
    tifffile = pytest.importorskip("tifffile")
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0].pages[0] if subifd else tif.pages[0]
        return page.tags[name].value


def opcode_header(opcode_id: int, params: bytes, version=(1, 3, 0, 0), flags=0) -> bytes:
    """An opcode: its 16-byte header, then ``params``."""
    import struct

    return struct.pack(">I4BII", opcode_id, *version, flags, len(params)) + params


def opcode_list(*opcodes: bytes) -> bytes:
    """An opcode list: the count, then the opcodes."""
    import struct

    return struct.pack(">I", len(opcodes)) + b"".join(opcodes)


def opcode_area(t=0, l=0, b=8, r=8, plane=0, planes=1, rp=1, cp=1) -> bytes:
    """An area spec (32 bytes)."""
    import struct

    return struct.pack(">8I", t, l, b, r, plane, planes, rp, cp)


def gain_map_params(gains, sv, sh, ov, oh, area=None) -> bytes:
    """The parameters of a GainMap of ``gains`` (points V, points H, planes)."""
    import struct

    import numpy as np

    g = np.asarray(gains, dtype=np.float32)
    pv, ph, planes = g.shape
    return ((area or opcode_area()) + struct.pack(">II4dI", pv, ph, sv, sh, ov, oh, planes)
            + g.astype(">f4").tobytes())


def encoder_meta():
    """The capture metadata the encoder stages' tests write (EXIF) and read back."""
    from isp import CameraMeta

    return CameraMeta(make="phone-isp", model="test phone", exposure_time_s=1 / 250, f_number=1.8,
                      iso=200.0, focal_length_mm=4.2, datetime="2026:11:21 09:08:07", lens="lens x")


def display_ramp(h=48, w=64):
    """(h, w, 3) float32 display RGB: smooth ramps in every channel and a
    red top-left 8 × 8 corner that marks the orientation."""
    import numpy as np

    y, x = np.mgrid[0:h, 0:w]
    rgb = np.stack([x / (w - 1), y / (h - 1), 0.25 + 0.5 * (x + y) / (h + w)], axis=2).astype(np.float32)
    rgb[:8, :8] = [1, 0, 0]
    return rgb


def warped_square_chart(warp: str):
    """The 600 × 800 chart of 3 × 4 slanted squares (σ 1 px; 5°, 8°, 11°)
    seen through ``warp``: "perspective" (at an angle), "barrel" (k = 0.08
    at the frame's half-width: curved sides) or "barrel_vignetting" (and
    35 % vignetting); float32, ground 0.8."""
    import cv2
    import numpy as np

    from calibration.sfr.synthetic import render_square_chart

    img = render_square_chart((600, 800), (3, 4), sigma_px=1.0, angles_deg=(5.0, 8.0, 11.0),
                              side=0.5).image.astype(np.float32)
    h, w = img.shape
    if warp == "perspective":
        src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
        dst = np.float32([[30, 20], [w - 10, 0], [w - 10, h], [30, h - 20]])
        return cv2.warpPerspective(img, cv2.getPerspectiveTransform(src, dst), (w, h), flags=cv2.INTER_CUBIC,
                                   borderValue=0.8)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    nx, ny = (xx - w / 2) / (w / 2), (yy - h / 2) / (w / 2)
    r2 = nx * nx + ny * ny
    out = cv2.remap(img, (w / 2 + nx * (1 + 0.08 * r2) * w / 2).astype(np.float32),
                    (h / 2 + ny * (1 + 0.08 * r2) * w / 2).astype(np.float32), cv2.INTER_CUBIC, borderValue=0.8)
    return out * (1 - 0.35 * r2 / r2.max()) if warp == "barrel_vignetting" else out
