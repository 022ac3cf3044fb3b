"""Plain functions the tests import: where the shared data lives
(``../shared/data`` beside the repo, or a skip), and the builders of small
synthetic PSF maps, devices and observations. The fixtures that wrap them
are in ``tests/conftest.py``."""

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
