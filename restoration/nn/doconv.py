"""DOConv: dilated omni-dimensional dynamic convolution (paper section 4.2).

A DOConv layer holds ``n`` kernels (the paper: four, dilations 1, 2, 3, 4) and
four attentions in the manner of ODConv [1]_: over the kernels (``α_w``),
over the input channels (``α_c``), over the output filters (``α_f``) and over
the ``k × k`` kernel positions (``α_s``).

Two properties shape this implementation, both from the export target (ONNX
Runtime, static INT8, two phone cores; see ``DESIGN.md``, ``export/``):

* **Constant convolution weights.** ODConv aggregates one weight per image
  and runs one grouped convolution; such a weight is an activation, which
  static INT8 leaves in float (no speed-up, measured). Here the ``n``
  kernels are ``n`` ordinary convolutions with constant weights; the kernel
  attention mixes their *outputs*, the channel attention scales the input
  activations and the filter attention the output activations. Where the
  attention is one vector per image this is the same function as ODConv's
  aggregated weight (:func:`doconv2d_dynamic_weight`, tested to 1e-5).
* **Tile-consistent attention.** Attention from a global average pool
  depends on what the pool sees, and a tile sees less than the frame. By
  default (``pool="local"``) the statistics are a box mean over a fixed
  window (``window`` pixels of the layer's resolution) plus the field
  position, so the attention is a per-pixel map and a tile whose overlap
  covers the network's receptive field reproduces the full-frame result in
  its interior (tested). The price is reach: the channel attention scales
  the input at every tap, so a layer reads ``d_max·r + window // 2``
  pixels around an output pixel. ``pool="global"`` keeps ODConv's
  per-image attention, for reference and for the equivalence tests.

Spatial attention (``α_s``, one weight per kernel tap) has no
constant-weight form in general; three choices, selected by ``spatial``:

========  ==========================================================  ======
spatial   training / inference                                        export
========  ==========================================================  ======
"none"    no ``α_s`` (ODConv's ``α_s ≡ 1``)                            n convs
"tap"     dynamic per-pixel ``α_s`` on every tap: the k×k conv is      n·k²
          split into its ``k²`` taps (shifted 1×1 convs, same MACs)   1×1 convs
          whose outputs are weighted by ``α_s``; exact                 + muls
"frozen"  trained as "tap"; in eval mode (and so in export) ``α_s``    n convs
          is replaced by its running mean over training, folded into
          the constant weights (like BatchNorm's running statistics)
========  ==========================================================  ======

A learned *constant* ``α_s`` is not offered: it spans the same functions as
``"none"`` (the kernel absorbs it).

Notes
-----
With ``x`` the input ``(N, C_in, H, W)``, ``W_i`` the kernels (``C_out ×
C_in/g × k × k``), ``d_i`` their dilations, ``t = (t_y, t_x) ∈
{-r..r}²`` the taps (``r = k // 2``), ``p`` a pixel and ``g`` the groups,
the layer computes (``⊙`` per channel)

.. math::

    y(p) = α_f(p) ⊙ \\sum_{i=1}^{n} α_{w,i}(p) \\sum_t α_{s,t}(p)\\,
           W_{i,t} \\, [α_c ⊙ x](p + d_i t) + b

with the attentions (``σ`` the logistic function, ``T`` the temperature)

.. math::

    h = \\mathrm{ReLU}(\\mathrm{pool}(F x) + G φ),\\quad
    α_c = σ(A_c h / T),\\ α_f = σ(A_f h / T),\\ α_s = σ(A_s h / T),\\
    α_w = \\mathrm{softmax}_i(A_w h / T)

``F, G, A_*`` 1×1 convolutions, ``φ`` the field features (omitted without
field encoding or with ``pool="global"``), ``pool`` the box mean of side
``window`` (:func:`box_mean`, zero outside the frame) or the global mean (ODConv pools
first and has a BatchNorm after ``F``; the mean commutes with ``F``, and
the norm is left out for the reasons given in :mod:`restoration.nn.network`). With
``pool="global"`` every ``α`` is constant over ``p`` and ``y = (\\sum_i
α_{w,i} α_f ⊙ α_c ⊙ α_s ⊙ \\tilde W_i) * x``, ODConv's eq. (3) [1]_ with
``\\tilde W_i`` the kernel ``W_i`` spread to dilation ``d_i`` on a common
``(d_{max}(k-1)+1)²`` grid. For a depthwise layer (``g = C_in = C_out``)
``α_f`` is dropped, as in ODConv: it would be a second per-channel scale.

Temperature: ODConv and DyConv [2]_ divide the attention logits by ``T``,
annealed linearly from 30 to 1 over the first epochs so that all kernels
train early on (:func:`temperature_schedule`, :func:`set_temperature`).
Export at ``T = 1``.

References
----------
.. [1] C. Li, A. Zhou, A. Yao, "Omni-Dimensional Dynamic Convolution",
   ICLR 2022 (code: github.com/OSVAI/ODConv).
.. [2] Y. Chen, X. Dai, M. Liu, D. Chen, L. Yuan, Z. Liu, "Dynamic
   Convolution: Attention over Convolution Kernels", CVPR 2020.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from isp.errors import ConfigError

#: spatial-attention choices (see the module docstring)
SPATIAL_MODES = ("none", "tap", "frozen")
#: where the attention statistics come from
POOL_MODES = ("local", "global", "field")


def choose(value: str, valid: tuple[str, ...], what: str) -> str:
    """``value`` if it is one of ``valid``, else ConfigError naming the
    option ``what``, the value and the valid ones."""
    if value not in valid:
        raise ConfigError(f"{what} must be one of {', '.join(map(repr, valid))}; got {value!r}")
    return value


class Attention(NamedTuple):
    """The four attentions of one DOConv layer for one input.

    Each map is ``(N, C, h, w)``: ``h, w`` the layer's spatial size for
    ``pool="local"``, ``1, 1`` for ``pool="global"``.
    """

    channel: Tensor  #: (N, C_in, h, w), in (0, 1)
    filter: Tensor | None  #: (N, C_out, h, w) in (0, 1); None for depthwise layers
    spatial: Tensor | None  #: (N, k·k, h, w) in (0, 1), taps row-major; None if unused
    kernel: Tensor | None  #: (N, n, h, w), softmax over the n kernels; None if n = 1


def box_mean(x: Tensor, window: int, kernels: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Mean over a ``window × window`` box around each pixel, (N, C, H, W),
    zero outside the image.

    Two depthwise convolutions with constant weights ``1/window`` (a
    ``window × 1`` and a ``1 × window`` one): they quantise to INT8 convs,
    where ``AveragePool`` with ``count_include_pad=0`` stayed a slow
    QLinearAveragePool (≈ 18 % of an INT8 DOConv UNet's time, measured).
    Zero padding darkens the mean near the frame border only, and a tile
    border lies within the discarded overlap, so tiles stay consistent.
    ``window`` odd. ``kernels``: the ``(C, 1, window, 1)`` and ``(C, 1, 1,
    window)`` weights, filled with ``1/window``, where the caller keeps them
    (a buffer exports as an initializer; a tensor made here from ``x.shape``
    would be computed in the graph).

    >>> box_mean(torch.ones(1, 1, 3, 5), 3)[0, 0]
    tensor([[0.4444, 0.6667, 0.6667, 0.6667, 0.4444],
            [0.6667, 1.0000, 1.0000, 1.0000, 0.6667],
            [0.4444, 0.6667, 0.6667, 0.6667, 0.4444]])
    """
    if window == 1:  # the pixel itself: no op in the graph (not two identity convs)
        return x
    r = window // 2
    if kernels is None:
        kv = x.new_full((x.shape[1], 1, window, 1), 1.0 / window)
        kernels = kv, kv.transpose(2, 3)
    c = kernels[0].shape[0]
    x = F.conv2d(x, kernels[0], padding=(r, 0), groups=c)
    return F.conv2d(x, kernels[1], padding=(0, r), groups=c)


def channel_softmax(z: Tensor) -> Tensor:
    """Softmax over dim 1 of (N, C, H, W), written out: ONNX Runtime's
    ``Softmax`` on axis 1 of NCHW transposes internally and ran ≈ 18× slower
    than these five element-wise ops (4 × 256² logits, 2 threads).

    >>> channel_softmax(torch.zeros(1, 4, 1, 1)).flatten().tolist()
    [0.25, 0.25, 0.25, 0.25]
    """
    e = torch.exp(z - z.amax(dim=1, keepdim=True))
    return e / e.sum(dim=1, keepdim=True)


class DOAttention(nn.Module):
    """The attention branch of :class:`DOConv2d` (see the module Notes).

    Parameters
    ----------
    in_channels, out_channels, kernel_size, n_kernels : int
        Of the convolution it serves.
    depthwise : bool
        Drop the filter attention (it would repeat the channel attention).
    spatial : {"none", "tap", "frozen"}
        Whether to produce ``α_s`` (not for "none" or ``kernel_size = 1``).
    pool : {"local", "global", "field"}
        Box mean of side ``window`` (tile-consistent) or the global mean of
        the content, plus the field features; or ``"field"``: the field
        features alone (position and, for a device-conditioned network, the
        device's descriptor), no image content. For one device and one
        frame the ``"field"`` attention is then a fixed map that can be
        computed once.
    window : int
        Box side in pixels of the layer's resolution, odd; 1: the pixel's own
        statistics (no box in the graph).
    field_channels : int
        Channels of the field features added to the hidden layer (0: none;
        ignored with ``pool="global"``, whose attention is per image).
    hidden : int
        Width of the hidden layer.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, n_kernels: int, *,
                 depthwise: bool, spatial: str, pool: str, window: int, field_channels: int,
                 hidden: int):
        super().__init__()
        self.pool = pool
        self.window = window
        self.temperature = 1.0
        if pool == "field" and not field_channels:
            raise ConfigError("pool='field' takes its attention from the field features: field_channels > 0")
        self.fc = nn.Conv2d(in_channels, hidden, 1) if pool != "field" else None
        self.field_fc = (nn.Conv2d(field_channels, hidden, 1, bias=pool == "field")
                         if field_channels and pool != "global" else None)
        # persistent: the ONNX exporter writes persistent buffers as initializers
        # (which INT8 quantisation needs) and the others as Constant nodes
        if window > 1 and pool != "field":  # window 1: the statistics are the pixel's own (box_mean is the identity)
            self.register_buffer("box_v", torch.full((hidden, 1, window, 1), 1.0 / window))
            self.register_buffer("box_h", torch.full((hidden, 1, 1, window), 1.0 / window))
        # one 1×1 conv per attention: slicing one shared head's output cost
        # more in ONNX Runtime (a Split between layout reorders) than it saves
        self.channel_head = nn.Conv2d(hidden, in_channels, 1)
        self.filter_head = None if depthwise else nn.Conv2d(hidden, out_channels, 1)
        self.kernel_head = nn.Conv2d(hidden, n_kernels, 1) if n_kernels > 1 else None
        # the frozen form does not compute this one at all
        self.spatial_head = (nn.Conv2d(hidden, kernel_size * kernel_size, 1)
                             if spatial != "none" and kernel_size > 1 else None)
        for conv in self.heads():  # start near uniform attention (σ = ½, softmax = 1/n)
            nn.init.normal_(conv.weight, std=0.01)
            nn.init.zeros_(conv.bias)

    def heads(self) -> list[nn.Conv2d]:
        """The attention heads this layer has."""
        return [c for c in (self.channel_head, self.filter_head, self.kernel_head, self.spatial_head)
                if c is not None]

    def forward(self, x: Tensor, field: Tensor | None = None, *, want_spatial: bool = True) -> Attention:
        """Attentions for ``x`` (N, C_in, H, W); ``field`` (N, F, H, W) when
        the layer was built with field channels and local pooling."""
        if self.pool == "field":
            if field is None:
                raise ConfigError("this DOConv layer takes its attention from the field features; pass `field`")
            h = self.field_fc(field)
        elif self.pool == "global":
            h = self.fc(x).mean(dim=(2, 3), keepdim=True)
        else:
            h = self.fc(x)
            h = box_mean(h, self.window, (self.box_v, self.box_h) if self.window > 1 else None)
            if self.field_fc is not None:
                if field is None:
                    raise ConfigError("this DOConv layer was built with field channels; pass `field`")
                h = h + self.field_fc(field)
        h = F.relu(h)
        inv_t = 1.0 / self.temperature

        def logits(head):
            z = head(h)
            return z * inv_t if inv_t != 1.0 else z

        return Attention(
            channel=torch.sigmoid(logits(self.channel_head)),
            filter=None if self.filter_head is None else torch.sigmoid(logits(self.filter_head)),
            spatial=(torch.sigmoid(logits(self.spatial_head))
                     if want_spatial and self.spatial_head is not None else None),
            kernel=None if self.kernel_head is None else channel_softmax(logits(self.kernel_head)),
        )


class DOConv2d(nn.Module):
    """Dilated omni-dimensional dynamic convolution, (N, C_in, H, W) →
    (N, C_out, H, W) (stride 1, "same" padding).

    Parameters
    ----------
    in_channels, out_channels : int
    kernel_size : int
        Odd; every kernel is ``k × k`` (the paper: 3).
    dilations : tuple of int
        One per kernel: ``(1, 2, 3, 4)`` in the paper; ``(1, 1, 1, 1)`` for
        the equal-dilation ablation.
    groups : int
        As in ``nn.Conv2d``; ``groups = in = out`` is depthwise (no filter
        attention).
    bias : bool
        A bias added after the attentions.
    spatial : {"none", "tap", "frozen"}
        Spatial attention (module docstring).
    pool : {"local", "global"}
        Attention statistics: a ``window`` box (tile-consistent, default) or
        the global mean (ODConv; not tile-consistent).
    window : int
        Box side, odd, in pixels of this layer's resolution (1: no box).
    field_channels : int
        Channels of the field features passed to :meth:`forward` (0: none).
    reduction, min_hidden : float, int
        Attention hidden width ``max(round(in_channels · reduction),
        min_hidden)`` (ODConv: 1/16 and 16; smaller layers here).
    momentum : float
        Of the running mean of ``α_s`` (used by ``spatial="frozen"`` in eval).

    Attributes
    ----------
    weight : Parameter, (n, C_out, C_in/groups, k, k)
    form : {"branch", "weight"}
        ``"branch"`` (default): constant-weight convolutions mixed on their
        outputs, the form that exports. ``"weight"``: ODConv's per-image
        aggregated weight (:func:`doconv2d_dynamic_weight`), only with
        ``pool="global"``; the oracle for the branch form (it applies the
        dynamic ``α_s`` whenever the layer has one, frozen or not).

    Examples
    --------
    >>> layer = DOConv2d(8, 8, groups=8)
    >>> layer(torch.zeros(2, 8, 12, 16)).shape
    torch.Size([2, 8, 12, 16])
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3,
                 dilations: tuple[int, ...] = (1, 2, 3, 4), *, groups: int = 1, bias: bool = False,
                 spatial: str = "none", pool: str = "local", window: int = 7,
                 field_channels: int = 0, reduction: float = 0.25, min_hidden: int = 8,
                 momentum: float = 0.01):
        super().__init__()
        choose(spatial, SPATIAL_MODES, "spatial")
        choose(pool, POOL_MODES, "pool")
        if kernel_size % 2 != 1 or window % 2 != 1:
            raise ConfigError(f"kernel_size and window must be odd; got {kernel_size}, {window}")
        if not dilations or min(dilations) < 1:
            raise ConfigError(f"dilations must be positive integers; got {dilations}")
        if in_channels % groups or out_channels % groups:
            raise ConfigError(f"groups={groups} must divide in_channels={in_channels} "
                              f"and out_channels={out_channels}")
        self.in_channels, self.out_channels = in_channels, out_channels
        self.kernel_size, self.groups = kernel_size, groups
        self.dilations = tuple(int(d) for d in dilations)
        self.spatial = spatial
        self.momentum = momentum
        self.form = "branch"
        n = len(self.dilations)
        self.weight = nn.Parameter(torch.empty(n, out_channels, in_channels // groups, kernel_size, kernel_size))
        for i in range(n):  # nn.Conv2d's default initialisation, per kernel
            nn.init.kaiming_uniform_(self.weight[i], a=math.sqrt(5))
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None
        depthwise = groups == in_channels == out_channels
        hidden = max(round(in_channels * reduction), min_hidden)
        self.attention = DOAttention(in_channels, out_channels, kernel_size, n, depthwise=depthwise,
                                     spatial=spatial, pool=pool, window=window,
                                     field_channels=field_channels, hidden=hidden)
        # running mean of α_s (kept for "tap" too, so a tap-trained layer can
        # be evaluated frozen); σ(0) = ½ before any training step
        self.register_buffer("spatial_mean", torch.full((kernel_size * kernel_size,), 0.5),
                             persistent=spatial != "none")

    def extra_repr(self) -> str:
        return (f"{self.in_channels}, {self.out_channels}, kernel_size={self.kernel_size}, "
                f"dilations={self.dilations}, groups={self.groups}, spatial={self.spatial!r}, "
                f"pool={self.attention.pool!r}, window={self.attention.window}")

    @property
    def dynamic_spatial(self) -> bool:
        """True when this call applies a per-pixel ``α_s`` (the tap form)."""
        return (self.attention.spatial_head is not None
                and (self.spatial == "tap" or (self.spatial == "frozen" and self.training)))

    def folded_weight(self) -> Tensor:
        """The constant kernels of the branch form, (n, C_out, C_in/g, k, k):
        ``W_i ⊙ ᾱ_s`` with the running-mean ``α_s`` for ``spatial="frozen"``,
        ``W_i`` otherwise."""
        if self.spatial == "frozen" and self.attention.spatial_head is not None:
            k = self.kernel_size
            return self.weight * self.spatial_mean.view(1, 1, 1, k, k)
        return self.weight

    def forward(self, x: Tensor, field: Tensor | None = None) -> Tensor:
        """``x`` (N, C_in, H, W) → (N, C_out, H, W); ``field`` (N, F, H, W)
        the field features when built with ``field_channels > 0``."""
        dyn = self.dynamic_spatial
        a = self.attention(x, field, want_spatial=dyn or self.form == "weight")
        if self.form == "weight":
            return doconv2d_dynamic_weight(x, self.weight, self.dilations, a, groups=self.groups,
                                           bias=self.bias)
        xc = x * a.channel
        if dyn:
            if self.training:
                with torch.no_grad():
                    m = a.spatial.mean(dim=(0, 2, 3))
                    self.spatial_mean.lerp_(m.to(self.spatial_mean), self.momentum)
            y = doconv2d_taps(xc, self.weight, self.dilations, a.spatial, a.kernel, groups=self.groups,
                              kernel_size=self.kernel_size)
        else:
            y = doconv2d_branches(xc, self.folded_weight(), self.dilations, a.kernel, groups=self.groups)
        if a.filter is not None:
            y = y * a.filter
        if self.bias is not None:
            y = y + self.bias.view(1, -1, 1, 1)
        return y


def doconv2d_branches(x: Tensor, weight: Tensor, dilations: tuple[int, ...],
                      kernel: Tensor | None, *, groups: int = 1) -> Tensor:
    """The export form without spatial attention: ``Σ_i α_w,i ⊙ conv_{d_i}(x, W_i)``.

    Parameters
    ----------
    x : (N, C_in, H, W) Tensor
        Input, channel attention already applied.
    weight : (n, C_out, C_in/groups, k, k) Tensor
        Constant kernels.
    dilations : n ints
    kernel : (N, n, h, w) Tensor or None
        Kernel attention (``h, w`` = ``H, W`` or 1); None: plain sum (n = 1).

    Returns
    -------
    (N, C_out, H, W) Tensor.
    """
    r = weight.shape[-1] // 2
    y = None
    for i, d in enumerate(dilations):
        yi = F.conv2d(x, weight[i], padding=d * r, dilation=d, groups=groups)
        if kernel is not None:
            yi = yi * kernel[:, i:i + 1]
        y = yi if y is None else y + yi
    return y


def doconv2d_taps(x: Tensor, weight: Tensor, dilations: tuple[int, ...], spatial: Tensor,
                  kernel: Tensor | None, *, groups: int = 1, kernel_size: int | None = None) -> Tensor:
    """The exact per-pixel form with spatial attention, constant weights:
    ``Σ_i Σ_t α_w,i(p) α_s,t(p) · (W_{i,t} x)(p + d_i t)``.

    Each ``k × k`` kernel is split into its ``k²`` taps; a tap is a 1×1
    convolution of the input shifted by ``d_i·t`` (zero padding), so the
    MACs equal those of the ``n`` dilated convolutions; the price is
    ``n·k²`` weighted adds per output value and many small operators.

    Parameters
    ----------
    x : (N, C_in, H, W) Tensor
    weight : (n, C_out, C_in/groups, k, k) Tensor
    dilations : n ints
    spatial : (N, k·k, h, w) Tensor
        ``α_s``, taps in row-major order, ``h, w`` = ``H, W`` or 1.
    kernel : (N, n, h, w) Tensor or None
    kernel_size : int, optional
        ``k`` as a Python int (default: read from ``weight``; pass it when
        tracing, where shapes are tensors).

    Returns
    -------
    (N, C_out, H, W) Tensor.
    """
    k = int(weight.shape[-1]) if kernel_size is None else kernel_size
    r = k // 2
    y = None
    for i, d in enumerate(dilations):
        p = d * r
        xp = F.pad(x, (p, p, p, p))
        for ty in range(k):
            for tx in range(k):
                # static slice ends (negative, or None) keep H, W dynamic in ONNX
                ey, ex = ty * d - 2 * p, tx * d - 2 * p
                xs = xp[:, :, ty * d:ey if ey else None, tx * d:ex if ex else None]
                u = F.conv2d(xs, weight[i][:, :, ty:ty + 1, tx:tx + 1], groups=groups)
                t = ty * k + tx
                beta = spatial[:, t:t + 1]
                if kernel is not None:
                    beta = beta * kernel[:, i:i + 1]
                u = u * beta
                y = u if y is None else y + u
    return y


def doconv2d_dynamic_weight(x: Tensor, weight: Tensor, dilations: tuple[int, ...], attention: Attention,
                            *, groups: int = 1, bias: Tensor | None = None) -> Tensor:
    """ODConv's train-time form: one aggregated kernel per image, one grouped conv.

    ``K_b = Σ_i α_w,i · α_f ⊙ α_c ⊙ α_s ⊙ W̃_i`` (module Notes), ``W̃_i`` the
    kernel spread to dilation ``d_i`` on a ``D × D`` grid, ``D =
    max(d)(k-1)+1``; ``y_b = K_b * x_b (+ b)``. Defined for per-image
    attention only (``pool="global"``: every map ``(N, C, 1, 1)``). Its
    kernels are activations, not constants: it does not quantise (see
    ``DESIGN.md``); kept as the oracle of :class:`DOConv2d`'s branch form.

    Parameters
    ----------
    x : (N, C_in, H, W) Tensor
    weight : (n, C_out, C_in/groups, k, k) Tensor
    dilations : n ints
    attention : Attention
        With maps of spatial size 1 × 1.
    groups : int
    bias : (C_out,) Tensor, optional

    Returns
    -------
    (N, C_out, H, W) Tensor.
    """
    maps = [m for m in attention if m is not None]
    if any(m.shape[-2:] != (1, 1) for m in maps):
        raise ConfigError("the dynamic-weight form needs per-image attention (pool='global'); "
                          "this layer's attention is a per-pixel map")
    n_img, c_in, h, w = x.shape
    _, c_out, c_ig, k, _ = weight.shape
    big_d = max(dilations) * (k - 1) + 1
    agg = x.new_zeros(n_img, c_out, c_ig, big_d, big_d)
    s = 1.0 if attention.spatial is None else attention.spatial.view(n_img, 1, 1, k, k)
    for i, d in enumerate(dilations):
        wi = weight[i].unsqueeze(0) * s
        if attention.kernel is not None:
            wi = wi * attention.kernel[:, i].view(n_img, 1, 1, 1, 1)
        span = d * (k - 1) + 1
        off = (big_d - span) // 2
        agg[:, :, :, off:off + span:d, off:off + span:d] += wi
    if attention.filter is not None:
        agg = agg * attention.filter.view(n_img, c_out, 1, 1, 1)
    # α_c over the input channels each output filter sees (its group's slice)
    ac = attention.channel.view(n_img, groups, 1, c_ig).expand(n_img, groups, c_out // groups, c_ig)
    agg = agg * ac.reshape(n_img, c_out, c_ig, 1, 1)
    y = F.conv2d(x.reshape(1, n_img * c_in, h, w), agg.reshape(n_img * c_out, c_ig, big_d, big_d),
                 padding=big_d // 2, groups=n_img * groups)
    y = y.view(n_img, c_out, h, w)
    if bias is not None:
        y = y + bias.view(1, -1, 1, 1)
    return y


def temperature_schedule(step: int, anneal_steps: int, t_start: float = 30.0, t_end: float = 1.0) -> float:
    """Attention temperature at ``step``: linear from ``t_start`` to ``t_end``
    over ``anneal_steps``, then ``t_end`` (DyConv [2]_ and ODConv [1]_: 30 → 1
    over the first 10 epochs).

    >>> [temperature_schedule(s, 10) for s in (0, 5, 10, 99)]
    [30.0, 15.5, 1.0, 1.0]
    """
    if anneal_steps <= 0 or step >= anneal_steps:
        return float(t_end)
    return float(t_start + (t_end - t_start) * step / anneal_steps)


def set_temperature(model: nn.Module, temperature: float) -> int:
    """Set the attention temperature of every DOConv layer in ``model``;
    returns how many layers were set."""
    if temperature <= 0:
        raise ConfigError(f"temperature must be > 0; got {temperature}")
    layers = [m for m in model.modules() if isinstance(m, DOAttention)]
    for m in layers:
        m.temperature = float(temperature)
    return len(layers)


def set_spatial(model: nn.Module, spatial: str) -> int:
    """Switch the spatial attention of every DOConv layer in ``model`` that
    has one between ``"tap"`` (exact) and ``"frozen"`` (running mean, folded)
    — e.g. to measure what freezing costs a tap-trained model. Returns how
    many layers changed."""
    choose(spatial, ("tap", "frozen"), "spatial")
    n = 0
    for m in model.modules():
        if isinstance(m, DOConv2d) and m.attention.spatial_head is not None:
            m.spatial = spatial
            n += 1
    return n
