"""The DOConv layer (restoration/nn/doconv.py).

Kind: property. The export form equals ODConv's dynamic-weight form and the
per-pixel definition; frozen spatial attention folds exactly; the
temperature schedule flattens the attentions; bad arguments are refused;
gradients reach every parameter; per-pixel attention reads the pixel alone.
"""

from __future__ import annotations

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
from restoration.nn.network import build_model
from tests.helpers import randomise_attention as _randomise_attention


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
