"""The ``dng_render`` stage (modules.dng_render) and the ``adobe`` look.

Kinds:

* published: against Adobe's DNG SDK 1.7.1. (a) ``dng_validate -cs1 -16``
  on small DNGs written here that exercise each part of the render the
  reference captures lack (ProfileHueSatMap 2.5-D and 3-D, two tables
  interpolated, the sRGB value encoding, LookTable, ProfileToneCurve,
  BaselineExposure + BaselineExposureOffset either sign, DefaultBlackRender,
  ColorMatrix without ForwardMatrix, a clipped Bayer ramp); skipped where
  ``dng_validate`` is not found ($DNG_VALIDATE, the PATH, or
  ``$ROOT/bin`` as ``../shared/tools/dngsdk/build_dng_validate.sh`` installs
  it). (b) Adobe's renders of real captures in
  ``../shared/data/raw/reference/adobe_dng_sdk_1.7.1/`` (the targets of
  ``benchmarks/adobe_parity.py``: mean CIEDE2000 ≤ 1, p95 ≤ 3, near-white
  chroma ≤ 3); the two small files run by default, the 12 and 9 MP GoPro
  files under ``slow``.
* property: a clipped gradient through a non-neutral white renders neutral
  (and the linear look's magenta shows the check can fail); threads and
  strips do not change the result; parameters, notes and refusals.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from isp import CFA, CameraMeta, ConfigError, Domain, Frame, Pipeline, create_stage
from isp.io.dng_write import write_dng
from isp.io.read import read_raw
from modules.common.dng_profile import hsv_to_rgb
from modules.dng_render import DngRender, render, render_plan
from tests.helpers import data_file

# camera colour of a plausible phone sensor (XYZ -> camera, D65 and A)
CM_A = np.array([[1.0134, -0.3954, -0.0402], [-0.4208, 1.1976, 0.2511], [-0.0620, 0.1460, 0.7041]])
CM_D65 = np.array([[0.6722, -0.0635, -0.0963], [-0.4287, 1.2460, 0.2028], [-0.0908, 0.2162, 0.5668]])
FM_A = np.array([[0.65, 0.2, 0.1143], [0.25, 0.85, -0.1], [0.0, -0.15, 0.97]])
FM_D65 = np.array([[0.7, 0.15, 0.1143], [0.28, 0.8, -0.08], [0.02, -0.2, 1.0]])
NEUTRAL = (0.55, 1.0, 0.7)


def _dng_validate() -> str | None:
    """Adobe's dng_validate: $DNG_VALIDATE, on the PATH, or where the build
    script puts it (``$ROOT/bin``, ROOT defaulting to ``$TMPDIR/dngsdk``)."""
    root = Path(os.environ.get("ROOT", Path(tempfile.gettempdir()) / "dngsdk"))
    for exe in (os.environ.get("DNG_VALIDATE"), shutil.which("dng_validate"), root / "bin" / "dng_validate"):
        if exe and Path(exe).is_file() and os.access(exe, os.X_OK):
            return str(exe)
    return None


def _meta(**changes) -> CameraMeta:
    base = dict(color_matrix_1=CM_A, color_matrix_2=CM_D65, forward_matrix_1=FM_A,
                forward_matrix_2=FM_D65, calibration_illuminant_1=17, calibration_illuminant_2=21,
                as_shot_neutral=NEUTRAL, unique_camera_model="phone-isp test camera")
    base.update(changes)
    return CameraMeta(**base)


def _hsv_chart(height: int = 96, width: int = 128) -> np.ndarray:
    """Unbalanced linear camera RGB in [0, 1]: hue across, saturation and
    two value levels down, brightening to the right."""
    yy, xx = np.mgrid[0:height, 0:width]
    half = height // 2
    hue = xx / width * 6.0
    sat = (yy % half) / (half - 1)
    val = np.where(yy < half, 0.9, 0.25) * (0.5 + 0.5 * xx / width)
    rgb = hsv_to_rgb(hue.astype(np.float32), sat.astype(np.float32), val.astype(np.float32))
    return rgb * np.asarray(NEUTRAL, np.float32)


def _table(rng, hues: int, sats: int, vals: int) -> np.ndarray:
    """Random (vals, hues, sats, 3) modifiers: hue shifts ±20°, scales near 1."""
    shape = (vals, hues, sats)
    return np.stack([rng.uniform(-20, 20, shape), rng.uniform(0.7, 1.3, shape),
                     rng.uniform(0.8, 1.2, shape)], axis=-1).astype(np.float32)


def _write_profile_dng(path: Path, data: np.ndarray, meta: CameraMeta, extra: list) -> Path:
    """A DNG Adobe's reader accepts (NewSubFileType 0, DNGVersion 1.6) with
    the raw or linear image ``data`` and extra profile tags ``(code, type,
    count, value)``, written with tifffile; colour tags as :func:`write_dng`."""
    import tifffile

    tmp = write_dng(path.with_suffix(".base.dng"), data, meta)
    with tifffile.TiffFile(tmp) as tif:
        page = tif.pages[0]
        tags = [(t.code, t.dtype, t.count, t.value, True) for t in page.tags.values()
                if t.code not in (254, 256, 257, 258, 259, 262, 273, 277, 278, 279, 284, 305, 50706)]
    tags.append((254, "I", 1, 0, True))
    tags.append((50706, "B", 4, bytes([1, 6, 0, 0]), True))
    tags.extend((c, t, n, v, True) for c, t, n, v in extra)
    tags.sort(key=lambda t: t[0])
    linear = data.ndim == 3
    with tifffile.TiffWriter(path) as tw:
        tw.write(data, photometric=34892 if linear else 32803, compression=None,
                 planarconfig="contig" if linear else None, extratags=tags, metadata=None,
                 software="phone-isp test")
    tmp.unlink()
    return path


def _floats(code: int, values) -> tuple:
    v = tuple(float(x) for x in np.ravel(values))
    return (code, "f", len(v), v)


def _srational(code: int, value: float) -> tuple:
    return (code, "2i", 1, (int(round(value * 10000)), 10000))


def _render_ours(path: Path) -> np.ndarray:
    frame = read_raw(path)
    p = Pipeline.default(correction={"model": "none"}).without("correction", "jpeg")
    return np.asarray(p.run(frame).data, np.float64)


def _render_adobe(exe: str, path: Path) -> np.ndarray:
    import tifffile

    out = path.with_suffix(".tif")
    subprocess.run([exe, "-cs1", "-16", "-tif", str(out), str(path)], check=True,
                   capture_output=True, timeout=60)
    return tifffile.imread(out).astype(np.float64) / 65535.0


# --------------------------------------------------------------------------
# published: dng_validate on DNGs written here

def _cases():
    rng = np.random.default_rng(7)
    curve = np.array([[0, 0], [0.1, 0.05], [0.3, 0.35], [0.6, 0.75], [1, 1]], np.float32)
    return {
        "HueSatMap 2.5-D": [(50937, "I", 3, (8, 4, 1)), _floats(50938, _table(rng, 8, 4, 1))],
        "HueSatMap 3-D, sRGB value encoding": [(50937, "I", 3, (6, 5, 4)),
                                               _floats(50938, _table(rng, 6, 5, 4)),
                                               (51107, "I", 1, 1)],
        "two HueSatMaps interpolated by temperature": [(50937, "I", 3, (8, 3, 1)),
                                                       _floats(50938, _table(rng, 8, 3, 1)),
                                                       _floats(50939, _table(rng, 8, 3, 1))],
        "LookTable 3-D, sRGB value encoding": [(50981, "I", 3, (12, 6, 5)),
                                               _floats(50982, _table(rng, 12, 6, 5)),
                                               (51108, "I", 1, 1)],
        "LookTable 2.5-D, sRGB value encoding": [(50981, "I", 3, (12, 6, 1)),
                                                 _floats(50982, _table(rng, 12, 6, 1)),
                                                 (51108, "I", 1, 1)],
        "ProfileToneCurve": [_floats(50940, curve)],
        "positive BaselineExposure + offset": [_srational(51109, 0.2)],
        "negative BaselineExposure + offset": [_srational(51109, -0.3)],
        "DefaultBlackRender none": [(51110, "I", 1, 1)],
        "everything": [(50937, "I", 3, (6, 5, 1)), _floats(50938, _table(rng, 6, 5, 1)),
                       _floats(50939, _table(rng, 6, 5, 1)), (50981, "I", 3, (8, 4, 3)),
                       _floats(50982, _table(rng, 8, 4, 3)), (51108, "I", 1, 1),
                       _floats(50940, [[0, 0], [0.25, 0.3], [1, 1]]), _srational(51109, -0.1)],
    }


CASES = _cases()
BASELINE = {"positive BaselineExposure + offset": 0.7, "negative BaselineExposure + offset": -0.8,
            "everything": 0.3}


@pytest.mark.published
@pytest.mark.parametrize("case", list(CASES) + ["ColorMatrix only (no ForwardMatrix)"])
def test_linear_dng_matches_dng_validate(case, tmp_path):
    """Each profile feature against Adobe's own render of the same file:
    16-bit outputs within 0.15 % (100 codes) everywhere and 3 codes on
    average (our curves are 65,536-entry tables sampled from the SDK's
    4096-interval ones)."""
    exe = _dng_validate()
    if exe is None:
        pytest.skip("dng_validate not found ($DNG_VALIDATE, PATH, or $TMPDIR/dngsdk/bin as "
                    "shared/tools/dngsdk/build_dng_validate.sh installs it)")
    data = np.clip(_hsv_chart() * 65535, 0, 65535).astype(np.uint16)
    meta = _meta(baseline_exposure=BASELINE.get(case, 0.0))
    if case.startswith("ColorMatrix only"):
        meta = meta.replace(forward_matrix_1=None, forward_matrix_2=None)
    path = _write_profile_dng(tmp_path / "case.dng", data, meta, CASES.get(case, []))
    ours, adobe = _render_ours(path), _render_adobe(exe, path)
    d = np.abs(ours - adobe) * 65535
    assert d.max() <= 100 and d.mean() <= 3, (d.max(), d.mean())


@pytest.mark.published
def test_clipped_bayer_ramp_matches_dng_validate(tmp_path):
    """A mosaic ramp past white in one, two and three channels, through a
    non-neutral white: ours (bilinear demosaic, camera-white clamp) against
    Adobe's render, within 0.1 % (16-bit)."""
    exe = _dng_validate()
    if exe is None:
        pytest.skip("dng_validate not found ($DNG_VALIDATE, PATH, or $TMPDIR/dngsdk/bin)")
    raw, _ = _clipped_ramp()
    meta = _meta(cfa=CFA.RGGB, black_level=np.full((1, 1, 1), 64.0), white_level=(4000.0,))
    data = np.round(raw * (4000 - 64) + 64).astype(np.uint16)
    path = _write_profile_dng(tmp_path / "ramp.dng", data, meta, [])
    ours, adobe = _render_ours(path), _render_adobe(exe, path)
    d = np.abs(ours - adobe)[2:-2, 2:-2] * 65535
    assert d.max() <= 65 and d.mean() <= 2, (d.max(), d.mean())


# --------------------------------------------------------------------------
# published: Adobe's renders of real captures (benchmarks/adobe_parity.py)

def _parity(name: str) -> dict:
    from benchmarks import adobe_parity

    data_file("raw", f"{name}.dng")
    data_file("raw", "reference", "adobe_dng_sdk_1.7.1", "index.json")
    return adobe_parity.parity(name, "adobe")


@pytest.mark.published
@pytest.mark.parametrize("name", ["skia_sample_1mp", "tinydng_colorchart"])
def test_small_captures_match_adobe_render(name):
    """The LG G4 linear DNG and the Canon 550D chart against Adobe's render:
    mean CIEDE2000 ≤ 1.0, p95 ≤ 3.0 (measured: 0.03 and 0.02)."""
    f = _parity(name)
    assert f["mean_de00"] <= 1.0 and f["p95_de00"] <= 3.0, f
    assert abs(f["mean_L_ours"] - f["mean_L_adobe"]) < 0.5, f


@pytest.mark.published
@pytest.mark.slow
@pytest.mark.parametrize("name", ["gopro_HERO6_GOPR0024", "gopro_FUSION_GPFR7066"])
def test_gopro_captures_match_adobe_render(name):
    """The 12 MP HERO6 and 9 MP FUSION (WarpRectilinear) captures at the
    reference's ½ scale: mean CIEDE2000 ≤ 1.0, p95 ≤ 3.0, and where Adobe's
    render is near white, a mean chroma ≤ 3 (Adobe: 0.4 and 1.2)."""
    f = _parity(name)
    assert f["mean_de00"] <= 1.0 and f["p95_de00"] <= 3.0, f
    assert f["near_white_chroma"] <= 3.0, f


# --------------------------------------------------------------------------
# properties: clipped highlights render neutral

def _clipped_ramp(height: int = 32, width: int = 512):
    """An RGGB mosaic (white level 1) of a slightly warm surface whose
    brightness ramps from 0.05 to 2.5 × white through the camera neutral
    :data:`NEUTRAL`: green clips first, then blue, then red. Returns the
    clipped mosaic and the (H, W) mask of pixels where any channel clipped."""
    k = np.linspace(0.05, 2.5, width)[None, :].repeat(height, axis=0)
    cam = k[..., None] * np.asarray(NEUTRAL) * np.array([1.08, 1.0, 0.9])
    pattern = CFA.RGGB.pattern
    mosaic = np.empty((height, width))
    for dy in (0, 1):
        for dx in (0, 1):
            mosaic[dy::2, dx::2] = cam[dy::2, dx::2, pattern[dy, dx]]
    return np.clip(mosaic, 0.0, 1.0), np.any(cam >= 1.0, axis=-1)


def _lab_chroma_hue(srgb: np.ndarray):
    import colour

    lab = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.clip(srgb, 0, 1)),
                            colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    return np.hypot(lab[..., 1], lab[..., 2]), np.degrees(np.arctan2(lab[..., 2], lab[..., 1])) % 360


def _ramp_frame() -> tuple[Frame, np.ndarray]:
    mosaic, clipped = _clipped_ramp()
    meta = _meta(cfa=CFA.RGGB, white_level=(1.0,), black_level=np.zeros((1, 1, 1)))
    return Frame(mosaic.astype(np.float32), Domain.RAW, meta), clipped


@pytest.mark.property
def test_clipped_gradient_renders_neutral_not_magenta():
    """The default look: wherever a raw channel is clipped, the render's
    chroma stays below 2 (C*ab), and the unclipped part keeps the surface's
    warm hue; the linear look, which has no camera-white clamp, turns the
    same pixels magenta (the check can fail)."""
    frame, clipped = _ramp_frame()
    inner = np.zeros_like(clipped)
    inner[2:-2, 2:-2] = True          # bilinear demosaic's border rows/columns
    out = Pipeline.default(correction={"model": "none"}).without("jpeg").run(frame)
    c, h = _lab_chroma_hue(np.asarray(out.data, np.float64))
    assert c[clipped & inner].max() < 2.0
    assert 60 < np.median(h[~clipped & inner]) < 100          # warm, not magenta
    linear = Pipeline.default("linear", correction={"model": "none"}).without("jpeg").run(frame)
    c_lin, h_lin = _lab_chroma_hue(np.asarray(linear.data, np.float64))
    assert c_lin[clipped & inner].max() > 15
    assert 300 < np.median(h_lin[clipped & inner]) < 345      # magenta


@pytest.mark.property
def test_clip_white_off_lets_the_tint_through():
    """Two stops darker, so that values past white stay visible: with the
    camera-white clamp the clipped part is neutral grey; without it, the
    unclipped red and blue over the clipped green tint it magenta."""
    frame, clipped = _ramp_frame()
    region = clipped.copy()
    region[:2] = region[-2:] = False
    region[:, :2] = region[:, -2:] = False
    out = {}
    for clip in (True, False):
        p = Pipeline.default(correction={"model": "none"},
                             dng_render={"clip_white": clip, "exposure": -1.5}).without("jpeg")
        out[clip] = _lab_chroma_hue(np.asarray(p.run(frame).data, np.float64))
    assert np.median(out[True][0][region]) < 0.2
    assert np.median(out[False][0][region]) > 1.0
    assert 300 < np.median(out[False][1][region]) < 345


# --------------------------------------------------------------------------
# properties: the stage

def _camera_frame(data=None, **meta) -> Frame:
    data = _hsv_chart(37, 53) / np.asarray(NEUTRAL, np.float32) if data is None else data
    return Frame(np.ascontiguousarray(data, np.float32), Domain.CAMERA_RGB, _meta(**meta),
                 neutral=NEUTRAL)


@pytest.mark.property
def test_registered_with_domains_and_defaults():
    st = create_stage("dng_render")
    assert isinstance(st, DngRender)
    assert st.consumes == (Domain.CAMERA_RGB,) and st.output_domain(Domain.CAMERA_RGB) is Domain.DISPLAY_RGB
    assert st.params()["shadows"] == 5.0 and st.params()["tone_curve"] == "auto"


@pytest.mark.property
def test_output_range_and_notes():
    out = DngRender()(_camera_frame())
    assert out.domain is Domain.DISPLAY_RGB and out.data.dtype == np.float32
    assert 0.0 <= out.data.min() and out.data.max() <= 1.0
    note = out.history[-1].note
    assert "ForwardMatrix" in note and "ACR3 default tone curve" in note and "black 0.005" in note


@pytest.mark.property
def test_threads_and_strips_do_not_change_the_result():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1.2, (101, 67, 3)).astype(np.float32)   # not a multiple of the strip height
    plan = render_plan(_meta(), NEUTRAL)
    one = render(x, plan, threads=1)
    two = render(x, plan, threads=2)
    np.testing.assert_array_equal(one, two)
    whole = render(np.concatenate([x] * 2, axis=0), plan, threads=2)
    np.testing.assert_array_equal(whole[:101], one)
    in_place = x.copy()
    assert render(in_place, plan, out=in_place) is in_place
    np.testing.assert_array_equal(in_place, one)


@pytest.mark.property
def test_neutral_stays_neutral_and_white_is_white():
    grey = np.full((4, 4, 3), 0.18, np.float32)
    white = np.full((4, 4, 3), 5.0, np.float32)      # far past white: clamped to it
    out = DngRender()(_camera_frame(np.concatenate([grey, white])))
    assert np.ptp(out.data[:4], axis=-1).max() < 2e-3
    np.testing.assert_allclose(out.data[4:], 1.0, atol=1e-6)


@pytest.mark.property
def test_exposure_and_black_render():
    frame = _camera_frame()
    base = DngRender()(frame).data
    brighter = DngRender(exposure=1.0)(frame).data
    assert brighter.mean() > base.mean() + 0.05
    no_black = DngRender()(frame.evolve(frame.data, meta=frame.meta.replace(default_black_render=1))).data
    assert DngRender(shadows=0.0)(frame).data.tolist() == no_black.tolist()
    offset = DngRender()(frame.evolve(frame.data, meta=frame.meta.replace(baseline_exposure_offset=1.0))).data
    np.testing.assert_allclose(offset, brighter, atol=1e-6)


@pytest.mark.property
def test_without_colour_matrix_balanced_camera_rgb_is_srgb():
    meta = CameraMeta(as_shot_neutral=NEUTRAL)
    grey = np.full((2, 2, 3), 0.4, np.float32)
    out = DngRender()(Frame(grey, Domain.CAMERA_RGB, meta, neutral=NEUTRAL))
    assert "no colour matrix" in out.history[-1].note
    assert np.ptp(out.data, axis=-1).max() < 2e-3


@pytest.mark.property
def test_bad_parameters_are_refused():
    for bad in ({"exposure": 20.0}, {"shadows": -1.0}, {"tone_curve": "s-curve"}, {"source": "nope"}):
        with pytest.raises((ConfigError, ValueError)):
            create_stage("dng_render", **bad)
