"""The pipeline (isp.pipeline): building and validation, the registry,
entry-point plug-ins, and whole images against LibRaw.

Kinds: property (build-time refusals name the stage; round trips of
configs; a plug-in from another installed package is listed and usable)
and published (whole images against LibRaw's ``rawpy.postprocess`` with
matched settings).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from isp import (CFA, CameraMeta, ConfigError, Domain, Frame, Pipeline, StageBase, create_stage,
                 list_stages, register_stage)
from isp.io.read import read_raw
from isp.pipeline import DEFAULT_STAGES, LOOKS, pipeline_config
from isp.stage import coerce_param


@pytest.mark.property
def test_default_pipeline_builds_and_chains_domains():
    p = Pipeline.default()
    assert [s.name for s in p.stages] == list(DEFAULT_STAGES)
    assert p.domains[0] is Domain.RAW
    assert p.output_domain is Domain.ENCODED
    # each stage's input domain is the previous one's output
    assert [d.value for d in p.domains] == [
        "raw", "raw", "raw_linear", "raw_linear", "raw_linear", "raw_linear", "camera_rgb",
        "camera_rgb", "camera_rgb", "camera_rgb", "display_rgb", "encoded"]
    linear = Pipeline.default("linear")
    assert [d.value for d in linear.domains][-5:] == [
        "camera_rgb", "camera_rgb", "linear_rgb", "display_rgb", "encoded"]


@pytest.mark.property
def test_looks_share_the_stages_before_the_render():
    adobe, linear = LOOKS["adobe"], LOOKS["linear"]
    slot = adobe.index("correction")
    assert adobe[:slot + 1] == linear[:slot + 1]
    assert adobe[slot + 1:] == ("highlights", "dng_render", "jpeg")
    assert linear[slot + 1:] == ("luminance", "ccm", "gamma", "jpeg")
    assert DEFAULT_STAGES == adobe
    # the adobe look demosaics as Adobe's SDK does unless a lens profile names
    # its model's method; an override still wins
    assert Pipeline.default().stages[adobe.index("demosaic")].params()["method"] == "auto"
    p = Pipeline.default(demosaic={"method": "menon2007"})
    assert p.stages[adobe.index("demosaic")].params()["method"] == "menon2007"
    assert Pipeline.default("linear").stages[linear.index("demosaic")].params()["method"] == "malvar2004"


@pytest.mark.property
def test_a_look_from_toml_and_from_pipeline_config(tmp_path):
    p = Pipeline.from_toml('look = "linear"\n')
    assert [s.name for s in p.stages] == list(LOOKS["linear"])
    cfg = pipeline_config(look="linear", overrides=[("gamma", "curve", "bt709")])
    assert [e["name"] for e in cfg["stage"]] == list(LOOKS["linear"])
    assert cfg["stage"][LOOKS["linear"].index("gamma")]["curve"] == "bt709"
    file = tmp_path / "look.toml"
    file.write_text('look = "adobe"\n')
    assert [e["name"] for e in pipeline_config(file)["stage"]] == list(LOOKS["adobe"])
    stages = tmp_path / "stages.toml"
    stages.write_text('[[stage]]\nname = "black_level"\n')
    with pytest.raises(ConfigError, match="either a look or a pipeline file"):
        pipeline_config(stages, look="linear")
    with pytest.raises(ConfigError, match="not both"):
        Pipeline.from_toml('look = "linear"\n[[stage]]\nname = "black_level"\n')
    with pytest.raises(ConfigError, match="unknown look 'film'; valid: adobe, linear"):
        Pipeline.default("film")


@pytest.mark.property
def test_builtin_stages_are_registered_through_entry_points():
    names = set(list_stages())
    assert set(DEFAULT_STAGES) <= names


@pytest.mark.property
@pytest.mark.parametrize("name", DEFAULT_STAGES)
def test_every_builtin_stage_declares_domains_and_defaults(name):
    st = create_stage(name)
    assert st.consumes and all(isinstance(d, Domain) for d in st.consumes)
    for d in st.consumes:
        assert isinstance(st.output_domain(d), Domain)
    # default parameters survive a TOML round trip, at the first domain the
    # stage accepts with them (the correction slot's packaged model: camera_rgb)
    for start in st.consumes:
        try:
            p = Pipeline([st], start=start)
            break
        except ConfigError:
            continue
    again = Pipeline.from_toml(p.to_toml())
    assert again.stages[0].params() == st.params()


@pytest.mark.property
def test_domain_chain_error_names_both_stages():
    with pytest.raises(ConfigError) as e:
        Pipeline.from_names(["black_level", "gamma"])
    msg = str(e.value)
    assert "'gamma'" in msg and "'black_level'" in msg and "raw_linear" in msg


@pytest.mark.property
def test_unknown_stage_lists_valid_names():
    with pytest.raises(ConfigError, match=r"unknown stage 'sharpen'.*valid: .*black_level"):
        Pipeline.from_toml('[[stage]]\nname = "sharpen"\n')


@pytest.mark.property
def test_unknown_parameter_names_stage_and_valid_parameters():
    with pytest.raises(ConfigError, match=r"stage #2 'demosaic': unknown parameter 'algo'; valid: method"):
        Pipeline.from_toml('[[stage]]\nname = "black_level"\n[[stage]]\nname = "demosaic"\nalgo = "x"\n')


@pytest.mark.property
def test_ill_typed_parameter_names_stage_and_value():
    with pytest.raises(ConfigError, match=r"'jpeg': parameter 'quality': expected an integer, got 'high'"):
        Pipeline.from_names(["jpeg"], {"jpeg": {"quality": "high"}}, start="display_rgb")
    with pytest.raises(ConfigError, match=r"'white_balance': parameter 'mode': expected one of"):
        Pipeline.from_names(["white_balance"], {"white_balance": {"mode": "auto"}}, start="raw_linear")
    with pytest.raises(ConfigError, match=r"quality must be 1..100, got 300"):
        Pipeline.from_names(["jpeg"], {"jpeg": {"quality": 300}}, start="display_rgb")


@pytest.mark.property
def test_bad_toml_is_a_config_error(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text("[[stage]\nname=")
    with pytest.raises(ConfigError, match="not valid TOML"):
        Pipeline.from_toml(f)
    with pytest.raises(ConfigError, match="cannot read config"):
        Pipeline.from_toml(tmp_path / "missing.toml")


@pytest.mark.property
def test_coerce_param_types():
    assert coerce_param(3, float) == 3.0
    assert coerce_param([1, 2, 3], tuple[float, float, float]) == (1.0, 2.0, 3.0)
    assert coerce_param(None, float | None) is None
    with pytest.raises(TypeError):
        coerce_param(True, float)  # a bool is not a number here
    with pytest.raises(TypeError):
        coerce_param([1, 2], tuple[float, float, float])


@pytest.mark.property
def test_code_registered_stage_runs_and_records_history():
    @register_stage
    @dataclass(frozen=True)
    class Halve(StageBase):
        """Halve linear values (test stage)."""

        name = "test_halve"
        consumes = (Domain.RAW_LINEAR,)
        factor: float = 0.5

        def process(self, frame):
            return frame.evolve(frame.data * self.factor, stage=self.name, note=f"x{self.factor}")

    p = Pipeline.from_toml('start = "raw_linear"\n[[stage]]\nname = "test_halve"\nfactor = 0.25\n')
    f = Frame(np.ones((4, 4), np.float32), Domain.RAW_LINEAR, CameraMeta(cfa=CFA.RGGB))
    out = p.run(f)
    assert np.allclose(out.data, 0.25)
    assert [str(s) for s in out.history] == ["test_halve: x0.25"]
    assert np.allclose(f.data, 1.0)  # frames are not modified in place


@pytest.mark.property
def test_run_refuses_frame_in_wrong_domain():
    p = Pipeline.from_names(["gamma"], start="linear_rgb")
    f = Frame(np.ones((2, 2, 3), np.float32), Domain.CAMERA_RGB, CameraMeta())
    with pytest.raises(ConfigError, match="starts at linear_rgb"):
        p.run(f)


PLUGIN = '''
from dataclasses import dataclass
from isp import Domain, StageBase
@dataclass(frozen=True)
class Invert(StageBase):
    """Invert display values (a third-party plug-in)."""
    name = "plugin_invert"
    consumes = (Domain.DISPLAY_RGB,)
    amount: float = 1.0

    def process(self, frame):
        return frame.evolve(self.amount - frame.data, stage=self.name)
'''


@pytest.mark.property
def test_entry_point_plugin_from_another_package(tmp_path):
    """A stage declared in another distribution's entry points is listed by
    `isp stages` and usable in a config (run in a subprocess so that the fake
    distribution is on the path from the start)."""
    pkg = tmp_path / "isp_plugin_demo"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent(PLUGIN))
    dist = tmp_path / "isp_plugin_demo-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: isp-plugin-demo\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[isp.stages]\nplugin_invert = isp_plugin_demo:Invert\n")
    env = {"PYTHONPATH": str(tmp_path)}
    import os

    env = {**os.environ, **env}
    out = subprocess.run([sys.executable, "-m", "isp", "stages"], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "plugin_invert" in out.stdout and "isp-plugin-demo" in out.stdout
    code = textwrap.dedent('''
        import numpy as np
        from isp import Pipeline, Frame, Domain, CameraMeta
        p = Pipeline.from_toml('start = "display_rgb"\\n[[stage]]\\nname = "plugin_invert"\\namount = 1.0\\n')
        f = Frame(np.full((2, 2, 3), 0.25, np.float32), Domain.DISPLAY_RGB, CameraMeta())
        print(float(p.run(f).data[0, 0, 0]))
    ''')
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "0.75"


# -- whole images against LibRaw ---------------------------------------------------

BAYER_DNGS = ["tinydng_colorchart.dng", "imageio_Blackmagic.dng",
              "SYNTHETIC_phone_S6meta_512x384.dng", "SYNTHETIC_phone_S6meta_5328x3000.dng"]


def _lab(srgb):
    import colour

    return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(srgb))


def _rawpy_reference(path):
    import rawpy

    with rawpy.imread(str(path)) as r:
        ref = r.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR, use_camera_wb=True,
                            output_color=rawpy.ColorSpace.sRGB, no_auto_bright=True,
                            adjust_maximum_thr=0.0, gamma=(2.4, 12.92), output_bps=16, user_flip=0,
                            highlight_mode=rawpy.HighlightMode.Clip)
        rgb_cam = r.color_matrix[:, :3].copy()
    return ref.astype(np.float32) / 65535.0, rgb_cam


@pytest.mark.published
@pytest.mark.parametrize("name", BAYER_DNGS)
def test_matches_rawpy_postprocess(raw_file, name):
    """Whole images against LibRaw (rawpy.postprocess) with matched settings.

    Matched: linear (bilinear) demosaic, camera white balance, sRGB output
    with the sRGB curve, no auto-brightening (and no LibRaw "adjust
    maximum", which otherwise rescales white to the brightest pixel),
    highlights clipped, no lens shading and no BaselineExposure on our side
    (LibRaw applies neither).

    "Same matrix": LibRaw's own camera→sRGB matrix (``rawpy.color_matrix``)
    given to our colour stage. Our DNG-spec colour (ForwardMatrix / dual
    illuminant, Bradford adaptation) is held to the same bound: it is a
    different colour model, so it differs where LibRaw's single-matrix model
    is approximate, but by less than 2 ΔE00 on average."""
    import colour

    path = raw_file(name)
    ref, rgb_cam = _rawpy_reference(path)
    frame = read_raw(path)
    oy, ox = frame.meta.origin
    h, w = frame.shape[:2]
    ref = ref[oy:oy + h, ox:ox + w] if ref.shape[:2] != (h, w) else ref
    step = 3 if h * w < 4e6 else 9    # a regular subsample keeps the 16 MP case quick
    results = {}
    for label, ccm in (("same matrix", {"matrix": tuple(rgb_cam.ravel())}), ("DNG colour", {})):
        p = Pipeline.from_names(["black_level", "white_balance", "demosaic", "ccm", "gamma"],
                                {"ccm": ccm, "demosaic": {"method": "bilinear"}})
        ours = p.run(frame).data
        b = 4  # LibRaw's and our border handling differ in the outermost pixels
        de = colour.delta_E(_lab(ours[b:-b:step, b:-b:step]), _lab(ref[b:-b:step, b:-b:step]),
                            method="CIE 2000")
        results[label] = float(de.mean())
    # measured: same matrix 0.013-0.05; DNG colour 0.56-0.78
    assert results["same matrix"] <= 2.0, results
    assert results["same matrix"] <= 0.1, results  # the pipelines agree, not just pass
    assert results["DNG colour"] <= 2.0, results
