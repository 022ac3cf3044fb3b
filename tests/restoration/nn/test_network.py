"""The restoration network (restoration/nn/network.py).

Kind: property. Every registered variant's shapes and MAC budget; space to
depth; group width; registry errors; padding; tile consistency; ONNX export
with constant conv weights and ONNX Runtime ↔ torch parity; the sqrt
encoding; the packed space-to-depth form; the residual high-pass.
"""

from __future__ import annotations

import functools
import io

import numpy as np
import pytest

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")
F = torch.nn.functional

from isp.errors import ConfigError
from restoration.nn.doconv import DOConv2d
from restoration.nn.macs import macs_per_pixel
from restoration.nn.network import (
    DEFAULT,
    build_model,
    forward_padded,
    list_models,
    pad_to_multiple,
)
from tests.helpers import randomise_attention as _randomise_attention


#: the export budget, MACs per output pixel (export issue: ≤ 2 s / 12 MP on 2 cores)
MAC_BUDGET = 20_000
SMALL = {"depths": (1, 1, 1)}


def _field(n, h, w, dtype=torch.float32):
    ys = (torch.arange(h, dtype=dtype) + 0.5) / h * 2 - 1
    xs = (torch.arange(w, dtype=dtype) + 0.5) / w * 2 - 1
    f = torch.stack(torch.meshgrid(xs, ys, indexing="xy"))
    return f.expand(n, 2, h, w)


# ---------------------------------------------------------------- the network

@functools.cache
def _full(variant):
    return build_model(variant)


@pytest.mark.parametrize("variant", list_models())
def test_variant_shapes_and_budget(variant):
    """Every registered variant: (N, 5 or 3, H, W) → (N, 3, H, W), ≤ 20 kMAC/px,
    near-identity when untrained, gradients to every parameter."""
    assert macs_per_pixel(_full(variant), (16, 16)) <= MAC_BUDGET
    torch.manual_seed(5)
    model = build_model(variant, **SMALL, **({"widths": _full(variant).config["widths"]}
                                             if variant == "static" else {}))
    x = torch.rand(2, model.in_channels, 16, 24)
    y = model(x)
    assert y.shape == (2, 3, 16, 24) and y.dtype == torch.float32
    assert (y - x[:, :3]).abs().mean() < 0.1  # residual output, small head at init
    y.square().mean().backward()
    dead = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not dead


def test_space_to_depth_4():
    model = build_model("doconv", scale=4, widths=(16, 32), **SMALL)
    assert model.input_multiple == 8
    assert model(torch.rand(1, 5, 16, 24)).shape == (1, 3, 16, 24)
    with pytest.raises(ConfigError, match="multiples of 8"):
        model(torch.rand(1, 5, 20, 24))
    with pytest.raises(ConfigError, match="scale must be 2 or 4"):
        build_model("doconv", scale=3)


def test_static_variant_has_equal_macs():
    ref = macs_per_pixel(_full("doconv"), (16, 16))
    static = _full("static")
    assert static.config["widths"][0] > DEFAULT["widths"][0]  # wider to match the attention MACs
    assert macs_per_pixel(static, (16, 16)) == pytest.approx(ref, rel=0.05)


def test_group_width_sets_the_blocks_conv_groups_and_macs():
    """``group_width`` channels per group: 1 is depthwise (no filter
    attention), ``channels`` dense (with it); the block conv's MACs grow
    with the group width, 4 kernels × 9 taps × width per output value."""
    dw = build_model("doconv", widths=(8, 16), depths=(0, 1, 0))
    dense = build_model("doconv", widths=(8, 16), depths=(0, 1, 0), group_width=16)
    assert dw.mid[0].conv.groups == 16 and dw.mid[0].conv.attention.filter_head is None
    assert dense.mid[0].conv.groups == 1 and dense.mid[0].conv.attention.filter_head is not None
    assert build_model("static", widths=(8, 16), group_width=4).mid[0].conv.groups == 4
    assert build_model("static", widths=(8, 16), group_width=0).mid[0].conv.groups == 1
    # the block conv runs at ¼ resolution: 1/16 of its MACs per output pixel
    extra = macs_per_pixel(dense, (16, 16)) - macs_per_pixel(dw, (16, 16))
    assert extra == pytest.approx(4 * 9 * 16 * (16 - 1) / 16, rel=0.02)
    with pytest.raises(ConfigError, match="group_width must divide"):
        build_model("doconv", widths=(8, 16), group_width=5)


def test_variant_differences():
    cfg = {v: _full(v).config for v in list_models()}
    assert cfg["no_field"]["field"] is False and _full("no_field").in_channels == 3
    assert cfg["equal_dilation"]["dilations"] == (1, 1, 1, 1)
    assert cfg["doconv"]["dilations"] == (1, 2, 3, 4)
    assert cfg["doconv_global"]["pool"] == "global"
    assert build_model("doconv").fov_encoding == "xy"


def test_registry_errors_name_the_valid_choices():
    with pytest.raises(ConfigError, match="valid: .*doconv.*static"):
        build_model("resnet")
    with pytest.raises(ConfigError, match="unknown argument.*width_mult"):
        build_model("doconv", width_mult=2)
    with pytest.raises(ConfigError, match="multiples of 4"):
        build_model("doconv", **SMALL)(torch.zeros(1, 5, 30, 32))
    with pytest.raises(ConfigError, match=r"\(N, 5, H, W\)"):
        build_model("doconv", **SMALL)(torch.zeros(1, 3, 32, 32))


def test_padding_helper():
    x = torch.cat([torch.rand(1, 3, 30, 45), _field(1, 30, 45)], dim=1)
    xp, size = pad_to_multiple(x, 4)
    assert xp.shape[-2:] == (32, 48) and size == (30, 45)
    # the field keeps its linear ramp in the padding
    want_x = (torch.arange(48) + 0.5) / 45 * 2 - 1
    want_y = (torch.arange(32) + 0.5) / 30 * 2 - 1
    assert torch.allclose(xp[0, 3], want_x.expand(32, 48), atol=1e-5)
    assert torch.allclose(xp[0, 4], want_y[:, None].expand(32, 48), atol=1e-5)
    assert torch.equal(xp[0, :3, 30:, :45], x[0, :3, 29:30, :].expand(3, 2, 45))  # replicated edge
    model = build_model("doconv", **SMALL)
    assert forward_padded(model, x).shape == (1, 3, 30, 45)


def test_padding_extrapolates_the_field_and_replicates_the_descriptor():
    """A conditioned network's input (RGB, x, y, K descriptor channels):
    the field after the RGB is extrapolated, the descriptor is not."""
    d = torch.rand(1, 4, 30, 45)
    x = torch.cat([torch.rand(1, 3, 30, 45), _field(1, 30, 45), d], dim=1)
    xp, _ = pad_to_multiple(x, 4)
    want_x = (torch.arange(48) + 0.5) / 45 * 2 - 1
    assert torch.allclose(xp[0, 3], want_x.expand(32, 48), atol=1e-5)
    assert torch.equal(xp[0, 5:, :30, 45:], d[0, :, :, 44:45].expand(4, 30, 3))
    assert torch.equal(xp[0, 5:, 30:, :45], d[0, :, 29:30, :].expand(4, 2, 45))


def test_a_conditioned_network_without_field_reads_the_descriptor_alone():
    """``field=False`` with descriptor channels (the conditioned design's
    no-field ablation): the input keeps its layout, the output ignores
    the field channels and follows the descriptor."""
    torch.manual_seed(1)
    model = build_model("device", widths=(8, 16), depths=(0, 1, 0), field=False, device=4).eval()
    assert model.in_channels == 9 and model.fov_encoding == "xy"
    for layer in model.modules():
        if isinstance(layer, DOConv2d):
            _randomise_attention(layer)
    with torch.no_grad():
        model.head[0].weight.mul_(10)
    x = torch.cat([torch.rand(1, 3, 32, 32), _field(1, 32, 32), torch.rand(1, 4, 32, 32)], dim=1)
    moved = x.clone()
    moved[:, 3:5] = torch.rand(1, 2, 32, 32)
    other = x.clone()
    other[:, 5:] = torch.rand(1, 4, 32, 32)
    with torch.no_grad():
        y, y_moved, y_other = model(x), model(moved), model(other)
    assert torch.equal(y, y_moved)
    assert torch.abs(y - y_other).max() > 1e-3


def test_tiles_match_the_full_frame():
    """Property: with local attention a tile gives the full frame's output
    wherever the tile extends at least the receptive radius beyond (tile
    origins on multiples of 4); ODConv's global pooling does not."""
    torch.manual_seed(6)
    h, w, x0, radius = 32, 192, 64, 63  # tile = columns 64.. of the frame; radius of SMALL
    x = torch.cat([torch.rand(1, 3, h, w), _field(1, h, w)], dim=1).double()
    for variant, consistent in (("doconv", True), ("doconv_global", False)):
        model = build_model(variant, **SMALL).double().eval()
        for blk in model.modules():
            if isinstance(blk, DOConv2d):
                _randomise_attention(blk, std=0.3)
        with torch.no_grad():
            full = model(x)[..., x0 + radius:]
            tile = model(x[..., x0:])[..., radius:]
        err = (full - tile).abs().max()
        assert (err < 1e-12) if consistent else (err > 1e-8), (variant, err)


@pytest.mark.filterwarnings("ignore:You are using the legacy TorchScript-based ONNX export")
@pytest.mark.filterwarnings("ignore:The feature will be removed")
@pytest.mark.filterwarnings("ignore:Constant folding - Only steps=1")  # F.pad's reversed pads
@pytest.mark.parametrize("variant", ["doconv", "doconv_spatial_frozen", "doconv_spatial_tap"])
def test_onnx_export_constant_weights_and_parity(variant, tmp_path):
    """Property (ONNX ↔ torch): opset 17, dynamic H and W, every Conv's weight
    an initializer (so static INT8 can quantise it), ORT output within 1e-4."""
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    torch.manual_seed(7)
    # the default in full; the spatial variants with one DOConv block (the
    # tap form is 36 convs per layer: slow to export, nothing new to check)
    model = build_model(variant, **({} if variant == "doconv" else {"depths": (0, 1, 0)}))
    if variant == "doconv_spatial_frozen":  # a running mean away from ½
        model.train()
        model(torch.rand(1, 5, 32, 32))
    model.eval()
    x = torch.cat([torch.rand(1, 3, 64, 96), _field(1, 64, 96)], dim=1)
    buf = io.BytesIO()
    # dynamo=False: the torch.export-based exporter needs onnxscript (not a dependency)
    torch.onnx.export(model, (x,), buf, dynamo=False, opset_version=17, input_names=["input"],
                      output_names=["output"],
                      dynamic_axes={"input": {0: "n", 2: "h", 3: "w"}, "output": {0: "n", 2: "h", 3: "w"}})
    graph = onnx.load_from_string(buf.getvalue()).graph
    inits = {i.name for i in graph.initializer}
    # the exporter shares equal initializers through Identity nodes
    alias = {n.output[0]: n.input[0] for n in graph.node if n.op_type == "Identity"}
    convs = [n for n in graph.node if n.op_type == "Conv"]
    assert convs and all(alias.get(n.input[1], n.input[1]) in inits for n in convs)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 2
    sess = ort.InferenceSession(buf.getvalue(), opts, providers=["CPUExecutionProvider"])
    for size in ((64, 96), (32, 128)):  # dynamic H, W
        xs = torch.cat([torch.rand(1, 3, *size), _field(1, *size)], dim=1)
        with torch.no_grad():
            ref = model(xs).numpy()
        got = sess.run(None, {"input": xs.numpy()})[0]
        assert np.abs(got - ref).max() <= 1e-4


def test_sqrt_encoding_is_the_identity_without_a_correction():
    """encoding="sqrt": the network works on u = √(max(x, 0) + c) and decodes
    u² − c, so with a zero head the output is the input wherever x ≥ 0 (and
    0 where the input was negative noise)."""
    model = build_model("doconv", encoding="sqrt", **SMALL).eval()
    with torch.no_grad():
        model.head[0].weight.zero_()
        model.head[0].bias.zero_()
        x = torch.rand(1, 5, 16, 24, dtype=torch.float32)
        x[:, 3:] = x[:, 3:] * 2 - 1
        x[0, 0, 0, 0] = -0.01
        y = model(x)
    want = x[:, :3].clamp(min=0)
    assert torch.allclose(y, want, atol=1e-6)
    with pytest.raises(ConfigError, match="encoding"):
        build_model("doconv", encoding="gamma")


@pytest.mark.parametrize("kw", [{}, {"scale": 4, "depths": (1, 1, 1)}, {"encoding": "sqrt", "field": False},
                                {"conv": "static"}, {"encoding": "sqrt", "highpass": 9},
                                {"scale": 4, "highpass": 3},
                                {"encoding": "sqrt", "highpass": 9, "highpass_domain": "linear"},
                                {"encoding": "sqrt", "scale": 4, "highpass": 3, "highpass_domain": "linear"},
                                {"group_width": 16}, {"conv": "static", "group_width": 4},
                                {"device": 4}, {"device": 3, "pool": "field", "scale": 4, "depths": (1, 1, 1)},
                                {"device": 4, "film": True}])
def test_space_to_depth_form_is_the_same_function(kw):
    """The export's packed form (stem and head reindexed) equals the model on
    the packed input, to float rounding; built here with plain reshapes."""
    from restoration.nn.network import SpaceToDepthForm, build_model, field_features

    torch.manual_seed(0)
    model = build_model("doconv", widths=(8, 16), **{"depths": (0, 1, 0), **kw}).eval()
    with torch.no_grad():
        model.head[0].weight.mul_(10)
        for name, p in model.named_parameters():
            if "film" in name:      # the modulation away from its identity start
                p.normal_(0.0, 0.3)
    s = model.scale
    x = torch.rand(2, model.in_channels, 8 * s, 12 * s)
    x[:, 3:] = x[:, 3:] * 2 - 1
    n, _, h, w = x.shape
    rgb = x[:, :3].reshape(n, 3, h // s, s, w // s, s).permute(0, 3, 5, 1, 2, 4).reshape(n, 3 * s * s, h // s, w // s)
    if model.field:   # the block means of the field and descriptor channels
        f = field_features(x[:, 3:], s)
        packed = torch.cat([rgb, f[:, :2], f[:, 3:]], 1)
    else:
        packed = rgb
    with torch.no_grad():
        ref = model(x)
        got = SpaceToDepthForm(model)(packed)
    unpacked = got.reshape(n, s, s, 3, h // s, w // s).permute(0, 3, 4, 1, 5, 2).reshape(n, 3, h, w)
    assert torch.abs(unpacked - ref).max() < 1e-5


def _block_means(v, m):
    """Means over 4 × 4 blocks (the upsampling's phase period) inside a margin ``m``."""
    return F.avg_pool2d(v[..., m:-m, m:-m], 4)


def _random_highpass_model(**kw):
    """A small random network without field input (whose smooth variation
    the box removes only to first order), its residual made large, and the
    margin (a multiple of 4) past which its output no longer sees the
    frame's border; float64, eval mode."""
    from restoration.nn.network import build_model, receptive_radius

    torch.manual_seed(1)
    model = build_model("doconv", widths=(8, 16), depths=(0, 1, 0), field=False,
                        **{"highpass": 9, "encoding": "sqrt", **kw}).double().eval()
    with torch.no_grad():
        model.head[0].weight.mul_(10)  # not more: u + r must stay > 0 for √ to be read back
        model.head[0].bias.uniform_(-0.05, 0.05)  # a level shift per channel
    m = -(-receptive_radius(model, 160) // 4) * 4
    return model.double(), m  # receptive_radius hands the model back in float32


@pytest.mark.parametrize("encoding", ["linear", "sqrt"])
def test_highpass_keeps_flat_fields(encoding):
    """Physics: an energy-conserving blur leaves flat regions flat, so its
    inverse must too. With ``highpass`` (and no field input, whose smooth
    variation the box removes only to first order) the network returns a
    flat field's level unchanged — its mean over every 4 × 4 block (the
    period of the upsampling's phases), to float rounding, wherever neither
    the frame's border nor the box's reach of it is seen — whatever its
    weights; without it the same random network shifts the level (a tone
    curve), by enough to see. With ``encoding="sqrt"`` the residual is
    added to ``u = √(x + c)``, so the block means hold for ``u``."""
    from restoration.nn.network import SQRT_OFFSET

    def enc(v):
        return torch.sqrt(v + SQRT_OFFSET) if encoding == "sqrt" else v

    for highpass, flat in ((9, True), (0, False)):
        model, m = _random_highpass_model(encoding=encoding, highpass=highpass)
        h = w = 2 * m + 16
        with torch.no_grad():
            y = model(torch.full((1, 3, h, w), 0.3, dtype=torch.float64))
        err = float((F.avg_pool2d(enc(y[..., m:-m, m:-m]), 4) - enc(torch.tensor(0.3))).abs().max())
        # the box's float32 weights (1/9) sum to 1 within 1e-7
        assert (err < 1e-6) if flat else (err > 1e-3), (highpass, err)


def test_linear_highpass_keeps_linear_means_of_texture_and_noisy_black():
    """Physics: a PSF that sums to 1 keeps the *linear* local means. With
    ``highpass_domain="linear"`` the residual is filtered after it is made
    linear, ``d = r (r + 2u)``, so the output's means over the box equal the
    input's for any weights, on texture (where the √x-domain high-pass moves
    them by the residual's local variance) and on a noisy black whose
    negatives the encoding clips (where the √x-domain one lifts the mean
    towards that of a clipped Gaussian, 0.4 σ). The reference is the input
    itself: a 9 × 9 box at ½ resolution removes what is constant over it,
    so the 18 × 18 px means agree to what varies within one box."""
    torch.manual_seed(2)
    errs = {}
    for domain in ("linear", "encoded"):
        model, m = _random_highpass_model(highpass_domain=domain)
        h = 2 * m + 72
        # texture: fine random detail on a level (its 18-px means are the level, to ~1 %)
        x = (0.3 + 0.2 * (torch.rand(1, 3, h, h, dtype=torch.float64) - 0.5)).clamp(min=0)
        black = 0.002 * torch.randn(1, 3, h, h, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
        with torch.no_grad():
            errs[domain] = [float((_block_means(model(v), m) - _block_means(v, m)).mean().abs())
                            for v in (x, black)]
    # linear: the texture's means kept to 0.07 % of its level, the black's to σ / 100
    # (measured 3.5e-5 and 4.5e-6); the √x-domain high-pass moves them 30× and 200× more
    assert errs["linear"][0] < 2e-4 and errs["linear"][1] < 2e-5, errs
    assert errs["encoded"][0] > 1e-3 and errs["encoded"][1] > 1e-3, errs


def test_linear_highpass_keeps_flat_fields_and_negatives():
    """A flat field, at any level, comes back exactly; a negative input
    (noise below black) passes through unclipped where the residual is 0."""
    from restoration.nn.network import build_model

    model, m = _random_highpass_model(highpass_domain="linear")
    h = 2 * m + 16
    for level in (0.0, 0.01, 0.3, 0.9):
        with torch.no_grad():
            y = model(torch.full((1, 3, h, h), level, dtype=torch.float64))
        # the box's float32 weights (1/9) sum to 1 within 1e-7
        assert float((_block_means(y, m) - level).abs().max()) < 1e-6 * max(level, 0.1), level
    zero = build_model("doconv", widths=(8, 16), depths=(0, 1, 0), field=False, highpass=9,
                       encoding="sqrt", highpass_domain="linear").eval()
    with torch.no_grad():
        zero.head[0].weight.zero_()
        zero.head[0].bias.zero_()
        x = torch.randn(1, 3, 16, 16) * 0.01
        assert torch.equal(zero(x), x)
    with pytest.raises(ConfigError, match="highpass_domain"):
        build_model("doconv", highpass=9, highpass_domain="srgb")


def test_highpass_removed_power_is_the_removed_means_and_frees_the_range():
    """``highpass_removed_power`` is the mean square of what the high-pass
    took out in the last training forward (0 without a high-pass or in
    eval), and minimising it shrinks the residual's range before the
    high-pass while the output stays the same function class: a few Adam
    steps on it alone cut it by > 10× (it is a null space of the output)."""
    from restoration.nn.network import ResidualHighPass, build_model, highpass_removed_power

    torch.manual_seed(0)
    x = torch.rand(2, 5, 32, 32)
    assert highpass_removed_power(build_model("doconv", widths=(8, 16), depths=(0, 1, 0))) == 0.0
    model = build_model("doconv", widths=(8, 16), depths=(0, 1, 0), highpass=9, encoding="sqrt",
                        highpass_domain="linear").train()
    with torch.no_grad():
        model.head[0].bias.fill_(0.05)   # a level the high-pass removes
    model(x)
    p0 = float(highpass_removed_power(model).detach())
    d = torch.randn(1, 12, 20, 20)
    hp = ResidualHighPass(12, 9).train()
    out = hp(d)
    assert torch.allclose(d - out, hp.removed, atol=1e-6) and p0 > 1e-4
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in range(30):
        model(x)
        loss = highpass_removed_power(model)
        opt.zero_grad()
        loss.backward()
        opt.step()
    model(x)
    assert float(highpass_removed_power(model).detach()) < p0 / 10
    model.eval()
    with torch.no_grad():
        model(x)
    assert highpass_removed_power(model) == 0.0


def test_highpass_rejects_other_windows():
    from restoration.nn.network import build_model

    with pytest.raises(ConfigError, match="highpass"):
        build_model("doconv", highpass=8)
    with pytest.raises(ConfigError, match="highpass"):
        build_model("doconv", highpass=5)


def test_a_device_network_reads_its_descriptor_and_field_attention_ignores_content():
    """The descriptor channels change the output; with ``pool="field"`` a
    DOConv's attention is the same whatever the image (a fixed map per
    device), with content pooling it is not."""
    from restoration.nn.network import field_features

    torch.manual_seed(4)
    h, w = 16, 24
    field = _field(1, h, w)
    desc = torch.rand(1, 4, h, w) * 2 - 1
    x1 = torch.cat([torch.rand(1, 3, h, w), field, desc], 1)
    x2 = torch.cat([torch.rand(1, 3, h, w), field, desc], 1)
    for pool, fixed in (("field", True), ("local", False)):
        model = build_model("device", device=4, pool=pool, **SMALL).eval()
        for blk in model.modules():
            if isinstance(blk, DOConv2d):
                _randomise_attention(blk, std=0.3)
        layer = model.mid[0].conv
        f2 = field_features(x1[:, 3:], 2 * model.scale)
        feats = [model.down(model.stem(x[:, :3]) + model.stem_field(field_features(x[:, 3:], model.scale)))
                 for x in (x1, x2)]
        with torch.no_grad():
            a1, a2 = (layer.attention(f, f2).channel for f in feats)
            other = torch.cat([x1[:, :5], -desc], 1)
            assert (model(x1) - model(other)).abs().max() > 1e-4       # the descriptor matters
        assert torch.equal(a1, a2) == fixed, pool


def test_a_device_network_keeps_the_field_channels_in_its_input():
    """With or without field features, the descriptor follows the field (x, y)
    in the input, the layout the correction stage feeds; K ≥ 0."""
    with pytest.raises(ConfigError, match="descriptor channels"):
        build_model("device", device=-1)
    with pytest.raises(ConfigError, match="film"):      # nothing to modulate by
        build_model("doconv", field=False, film=True)
    no_field = build_model("device", field=False)
    assert no_field.in_channels == 5 + 16 and no_field.fov_encoding == "xy"
    assert build_model("device").in_channels == 5 + 16 and build_model("device_attention").config["pool"] == "field"
