"""DOConv layer and restoration network (restoration/nn/doconv.py, network.py, macs.py).

Property tests: the export form equals ODConv's dynamic-weight form and the
per-pixel definition; frozen spatial attention folds exactly; MAC budget;
tile consistency; gradients; ONNX export with constant conv weights and
ONNX Runtime ↔ torch parity.
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
from restoration.nn.doconv import (
    Attention,
    DOConv2d,
    set_spatial,
    set_temperature,
    temperature_schedule,
)
from restoration.nn.macs import count_macs, macs_per_pixel
from restoration.nn.network import (
    DEFAULT,
    build_model,
    forward_padded,
    list_models,
    pad_to_multiple,
)

#: the export budget, MACs per output pixel (export issue: ≤ 2 s / 12 MP on 2 cores)
MAC_BUDGET = 20_000
SMALL = {"depths": (1, 1, 1)}


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """These tensors are tiny: one intra-op thread is faster than a pool (and
    far faster on a busy machine)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _randomise_attention(layer, std=0.5, seed=0):
    """Attention weights far from their near-uniform initialisation, so the
    attentions differ between images, pixels and kernels."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in layer.attention.parameters():
            p.copy_(torch.randn(p.shape, generator=g, dtype=p.dtype) * std)


def _field(n, h, w, dtype=torch.float32):
    ys = (torch.arange(h, dtype=dtype) + 0.5) / h * 2 - 1
    xs = (torch.arange(w, dtype=dtype) + 0.5) / w * 2 - 1
    f = torch.stack(torch.meshgrid(xs, ys, indexing="xy"))
    return f.expand(n, 2, h, w)


# ------------------------------------------------------------------ the layer

LAYERS = [  # (in, out, groups)
    pytest.param(6, 5, 1, id="dense"),
    pytest.param(6, 4, 2, id="grouped"),
    pytest.param(8, 8, 8, id="depthwise"),
]


@pytest.mark.parametrize("spatial", ["none", "tap"])
@pytest.mark.parametrize("cin,cout,groups", LAYERS)
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_branch_form_equals_dynamic_weight(cin, cout, groups, spatial, dtype, tol):
    """Property: with per-image attention (pool="global"), the constant-weight
    branch form (kernel attention on the branch outputs, channel/filter
    attention on activations, taps for α_s) is ODConv's aggregated-weight conv."""
    torch.manual_seed(1)
    layer = DOConv2d(cin, cout, groups=groups, spatial=spatial, pool="global", bias=True).to(dtype)
    _randomise_attention(layer)
    x = torch.randn(3, cin, 13, 18, dtype=dtype)
    y_branch = layer(x)
    layer.form = "weight"
    y_weight = layer(x)
    assert y_branch.shape == (3, cout, 13, 18)
    assert (y_branch - y_weight).abs().max() <= tol * y_weight.abs().max()
    # the attentions really differ between the images of the batch
    a = layer.attention(x)
    assert (a.kernel[0] - a.kernel[1]).abs().max() > 1e-3


def _per_pixel_reference(x, weight, dilations, a: Attention, groups):
    """The Notes equation, literally: every output pixel gathers its taps
    (F.unfold) and weights them with that pixel's attentions."""
    n, _, h, w = x.shape
    _, cout, cig, k, _ = weight.shape
    xc = x * a.channel
    y = 0
    for i, d in enumerate(dilations):
        cols = F.unfold(xc, k, dilation=d, padding=d * (k // 2)).view(n, groups, cig, k * k, h, w)
        wi = weight[i].view(groups, cout // groups, cig, k * k)
        s = a.spatial.view(n, 1, 1, k * k, h, w) if a.spatial is not None else 1.0
        yi = torch.einsum("gocT,ngcThw->ngohw", wi, cols * s).reshape(n, cout, h, w)
        y = y + a.kernel[:, i:i + 1] * yi
    return y if a.filter is None else y * a.filter


@pytest.mark.parametrize("spatial", ["none", "tap"])
@pytest.mark.parametrize("cin,cout,groups", LAYERS)
def test_per_pixel_attention_matches_definition(cin, cout, groups, spatial):
    """Property: with local (per-pixel) attention, the layer computes the
    Notes equation, including per-pixel spatial attention in the tap form."""
    torch.manual_seed(2)
    layer = DOConv2d(cin, cout, groups=groups, spatial=spatial, field_channels=3).double()
    _randomise_attention(layer)
    x = torch.randn(2, cin, 11, 14, dtype=torch.float64)
    fld = torch.randn(2, 3, 11, 14, dtype=torch.float64)
    a = layer.attention(x, fld)
    assert a.kernel.shape == (2, 4, 11, 14)
    ref = _per_pixel_reference(x, layer.weight, layer.dilations, a, groups)
    assert torch.allclose(layer(x, fld), ref, atol=1e-12)


def test_dynamic_weight_refuses_per_pixel_attention():
    layer = DOConv2d(4, 4)
    layer.form = "weight"
    with pytest.raises(ConfigError, match="per-image"):
        layer(torch.zeros(1, 4, 8, 8))


def test_frozen_spatial_attention_folds_into_constant_weights():
    """Property: spatial="frozen" uses the running mean of α_s in eval mode,
    which equals the tap form with that constant α_s, and the running mean
    follows the training batches."""
    torch.manual_seed(3)
    layer = DOConv2d(6, 6, groups=6, spatial="frozen", momentum=1.0).double()
    _randomise_attention(layer)
    x = torch.randn(2, 6, 12, 12, dtype=torch.float64)
    layer.train()
    layer(x)  # momentum 1: the running mean is this batch's mean
    want = layer.attention(x).spatial.mean(dim=(0, 2, 3))
    assert torch.allclose(layer.spatial_mean, want)
    layer.eval()
    a = layer.attention(x)
    a_const = a._replace(spatial=layer.spatial_mean.view(1, 9, 1, 1).expand(2, 9, 12, 12))
    ref = _per_pixel_reference(x, layer.weight, layer.dilations, a_const, 6)
    assert torch.allclose(layer(x), ref, atol=1e-12)
    # switching a trained layer between the exact and the frozen form
    assert set_spatial(layer, "tap") == 1 and layer.dynamic_spatial
    assert set_spatial(layer, "frozen") == 1 and not layer.dynamic_spatial


def test_temperature():
    assert temperature_schedule(0, 100) == 30.0
    assert temperature_schedule(50, 100) == pytest.approx(15.5)
    assert temperature_schedule(100, 100) == temperature_schedule(10**6, 100) == 1.0
    layer = DOConv2d(4, 4)
    _randomise_attention(layer, std=2.0)
    x = torch.randn(1, 4, 16, 16)
    assert set_temperature(layer, 1e4) == 1
    # a high temperature flattens every attention: softmax → 1/n, sigmoid → ½
    a = layer.attention(x)
    assert torch.allclose(a.kernel, torch.full_like(a.kernel, 0.25), atol=1e-3)
    assert torch.allclose(a.channel, torch.full_like(a.channel, 0.5), atol=1e-3)
    with pytest.raises(ConfigError):
        set_temperature(layer, 0)


def test_layer_rejects_bad_arguments():
    with pytest.raises(ConfigError, match="spatial must be one of"):
        DOConv2d(4, 4, spatial="dynamic")
    with pytest.raises(ConfigError, match="odd"):
        DOConv2d(4, 4, kernel_size=2)
    with pytest.raises(ConfigError, match="groups"):
        DOConv2d(4, 6, groups=4)
    with pytest.raises(ConfigError, match="pass `field`"):
        DOConv2d(4, 4, field_channels=3)(torch.zeros(1, 4, 8, 8))


def test_gradient_reaches_every_parameter():
    """Property: every weight, attention head and the field branch of a dense
    DOConv with all four attentions gets a non-zero gradient."""
    torch.manual_seed(4)
    layer = DOConv2d(6, 5, spatial="tap", field_channels=3, bias=True)
    layer(torch.randn(2, 6, 12, 12), torch.randn(2, 3, 12, 12)).square().sum().backward()
    dead = [n for n, p in layer.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not dead
    assert {"channel", "filter", "kernel", "spatial"} <= {
        n.split(".")[1].removesuffix("_head") for n, _ in layer.named_parameters() if "_head" in n}


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


def test_macs_counter_sees_functional_convs():
    """The DOConv branches are F.conv2d calls (no nn.Conv2d module): counted."""
    layer = DOConv2d(8, 8, groups=8).eval()
    macs = count_macs(layer, torch.zeros(1, 8, 10, 10))
    assert macs["total"] - macs["attention"] == 4 * 9 * 8 * 100


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
                                {"group_width": 16}, {"conv": "static", "group_width": 4}])
def test_space_to_depth_form_is_the_same_function(kw):
    """The export's packed form (stem and head reindexed) equals the model on
    the packed input, to float rounding; built here with plain reshapes."""
    from restoration.nn.network import SpaceToDepthForm, build_model, field_features

    torch.manual_seed(0)
    model = build_model("doconv", widths=(8, 16), **{"depths": (0, 1, 0), **kw}).eval()
    with torch.no_grad():
        model.head[0].weight.mul_(10)
    s = model.scale
    x = torch.rand(2, model.in_channels, 8 * s, 12 * s)
    x[:, 3:] = x[:, 3:] * 2 - 1
    n, _, h, w = x.shape
    rgb = x[:, :3].reshape(n, 3, h // s, s, w // s, s).permute(0, 3, 5, 1, 2, 4).reshape(n, 3 * s * s, h // s, w // s)
    packed = torch.cat([rgb, field_features(x[:, 3:5], s)[:, :2]], 1) if model.field else rgb
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


def test_pixel_attention_reads_the_pixel_alone_and_narrows_the_radius():
    """``window = 1``: each pixel's attention comes from its own features
    and field position (no box in the graph, no buffers), so a change
    elsewhere leaves it alone, and each block reads ``window // 2`` fewer
    pixels: on the e9 default (three blocks at ¼ resolution) 3 × 3 × 4 =
    36 px less radius than the 7² box (62 against 98 px)."""
    from restoration.nn.doconv import DOAttention
    from restoration.nn.network import receptive_radius

    torch.manual_seed(2)
    att = DOAttention(8, 8, 3, 4, depthwise=False, spatial="none", pool="local", window=1,
                      field_channels=0, hidden=8)
    assert not any("box" in k for k in att.state_dict())
    for conv in att.heads():
        torch.nn.init.normal_(conv.weight, std=0.5)
    x = torch.rand(1, 8, 9, 9)
    a = att(x)
    y = x.clone()
    y[..., 4, 4] += 1.0
    b = att(y)
    for ma, mb in ((a.channel, b.channel), (a.filter, b.filter), (a.kernel, b.kernel)):
        d = (ma - mb).abs().amax(dim=1)[0]
        assert d[4, 4] > 1e-3 and d.sum() == d[4, 4]   # the changed pixel's attention alone
    e9 = {"encoding": "sqrt", "highpass": 9, "highpass_domain": "linear", "group_width": 0,
          "widths": (16, 48), "depths": (0, 3, 0)}
    assert receptive_radius(build_model("doconv", **e9, window=7)) == 98
    assert receptive_radius(build_model("doconv", **e9, window=1)) == 62
