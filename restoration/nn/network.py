"""The restoration network: a reduced-stage UNet of ConvNeXt-style blocks
whose spatial convolution is a DOConv (paper section 4.2, Fig. "network").

Layout (``c1, c2 = widths``, default 16, 64; ``d1, d2, d3 = depths``,
default 0, 4, 0; resolutions relative to the input)::

    RGB (3, H, W) ─ stem 6×6/2 ─┐                                          ┌─ + RGB ─ out (3, H, W)
    field (2, H, W) → φ½ ─ 1×1 ─┴─ (+) c1 ─ d1 blocks ─┬─ ... ─ d3 blocks ─ head 3×3 → 12 ─ PixelShuffle 2
                                          (½)          │               (½)
                             down 2×2/2 → c2 ─ d2 blocks (¼, field φ¼) ─ up 1×1 → 4·c1 ─ PixelShuffle 2 ─ (+ skip)

* **Space-to-depth first.** Every layer runs at ½ or ¼ resolution. The
  stem is a 6×6 conv of stride 2 (``3·scale`` of stride ``scale``): the same
  function as PixelUnshuffle followed by a 3×3 conv, without the 6-D
  transpose that cost 8 % of an INT8 run.
* **The DOConv blocks sit at ¼ resolution** (the default ``depths`` has no
  block at ½). Measured with ONNX Runtime on 2 threads of this project's
  x86 machine (AVX2, no VNNI; ``benchmarks/doconv_speed.py`` and the
  per-operator profile it was designed with): an INT8 depthwise conv runs
  2× *slower* than in float, dense 3×3 convs 1.5–1.9× faster, and a
  per-pixel attention product costs a memory pass at its resolution, so
  every DOConv at ½ resolution cost as much as four at ¼. The previous
  default (widths 32, 64, depths 2, 4, 2: 14.2 kMAC/px) ran 542 ms/MP in
  INT8 on 512² tiles, 647 ms/MP through the correction stage on 12 MP;
  this one (6.7 kMAC/px) ≈ 157 ms per computed MP inside the model and
  193–222 ms/MP through the stage (``benchmarks/correction.py``, which
  prints both), and on the toy task
  (``benchmarks/doconv_toy.py``, 400 steps) it lost 0.4 dB of the former's
  1.2 dB gain, where a space-to-depth factor of 4 at the same speed lost
  0.8 dB.
* **Blocks** (ConvNeXt [1]_): ``x + pw₂(ReLU(pw₁(DOConv_dw(x, φ))))``, the
  depthwise 7×7 replaced by a depthwise DOConv (3×3 kernels, dilations
  1–4: a 9×9 footprint). No normalisation: LayerNorm has no INT8 kernel in
  ONNX Runtime's CPU provider (it would run in float between Q/DQ pairs), BatchNorm's
  batch statistics hurt restoration networks (EDSR [2]_ removed them) and
  a frame-level norm would break tile consistency. ReLU instead of GELU:
  it fuses into the INT8 convolution (QLinearConv), GELU does not. The
  residual branch's last 1×1 conv starts at 0.1 of its default scale (what
  layer scale does at initialisation, without a Mul in the graph).
* **Field position** ``(x, y) ∈ [-1, 1]`` of every pixel on the full frame
  (channels 3–4 of the input, :func:`modules.correction.field_coordinates`)
  enters as ``φ = (x, y, x² + y²)`` averaged to each resolution: into the
  stem, and into every DOConv's attention (spatially varying attention
  maps, tile-consistent by construction).
* **Device descriptor** (``device = K > 0``): a network shared by every
  module of a lens design reads the module's calibration, ``K`` numbers
  per field region (``device/v1``, :mod:`isp.io.device`), interpolated to
  each pixel and given as ``K`` more input channels after the field
  position. They join ``φ``, so they enter the stem and every DOConv's
  attention; with ``pool="field"`` the attention is driven by position and
  descriptor alone, a fixed map for one device. With ``film`` they also
  scale and shift, per channel and pixel, the stem's output and every
  block's spatial-conv output (FiLM [3]_; 1×1 convs of the features,
  starting at the identity): the descriptor then reaches the filters that
  do the deconvolution, not only their bias and their kernels' mix. For
  one device the scales and shifts are fixed maps.
* **Residual output**: the network predicts a correction added to the
  input RGB; the head starts small, so an untrained network is close to the
  identity.
* **Local means kept** (``highpass``, box side in ½-resolution pixels, a
  power of 3; 0: off): the residual minus its box mean, per packed channel
  (:class:`ResidualHighPass`). A PSF normalised to 1 moves no light further
  than its own reach, so its inverse leaves every mean over a larger region
  unchanged. Without this constraint the e9 network learns part of its
  sharpening as a tone curve: on flat fields at the slot it darkened 0.01
  by 7.8 % and brightened 0.7 by 2.0 % (FP32,
  ``benchmarks/flat_fields.py``), and it moved the
  demo's ColorChecker by 0.85 ΔE00 (``isp demo``). Its training pairs are
  unbiased to 0.1 % in the mean; the network finds the curve a cheap
  stand-in for the contrast that blur takes from natural images. The light
  a PSF keeps is linear, so the means to keep are linear:
  ``highpass_domain="linear"`` filters the residual the network makes in
  linear RGB, ``r (r + 2u)`` with ``u = √x`` (the default config's
  choice); ``"encoded"`` filters ``r`` itself, which keeps
  the means of ``u`` only.

Input ``(N, 5 + K, H, W)`` (``(N, 3, H, W)`` without field encoding), ``H`` and
``W`` multiples of :attr:`DOConvUNet.input_multiple` (4); other sizes go
through :func:`forward_padded`. Output ``(N, 3, H, W)``, float32 linear
camera RGB, not clipped.

Tiling: with the default local attention nothing depends on the extent of
the input, so a tile whose origin is a multiple of 4 (the ¼-resolution grid)
and whose context reaches :func:`receptive_radius` beyond the kept core
reproduces the full-frame output exactly (tested); in practice the
influence decays well inside that radius (``benchmarks/doconv_toy.py``
prints the tile error by overlap for a trained model).

Variants (``build_model(variant)``, :func:`list_models`) cover the paper's
ablations (section 5.4) and the export choices of the spatial attention.

References
----------
.. [1] Z. Liu, H. Mao, C.-Y. Wu, C. Feichtenhofer, T. Darrell, S. Xie,
   "A ConvNet for the 2020s", CVPR 2022.
.. [2] B. Lim, S. Son, H. Kim, S. Nah, K. M. Lee, "Enhanced Deep Residual
   Networks for Single Image Super-Resolution", CVPRW 2017.
.. [3] E. Perez, F. Strub, H. de Vries, V. Dumoulin, A. Courville, "FiLM:
   Visual Reasoning with a General Conditioning Layer", AAAI 2018.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from isp.errors import ConfigError

from restoration.nn.doconv import POOL_MODES, SPATIAL_MODES, DOConv2d, choose

#: ``conv`` choices of the blocks' spatial convolution
CONV_KINDS = ("doconv", "static")
#: field features per pixel: x, y, x² + y²
FIELD_FEATURES = 3
#: ``encoding`` choices: the network works on linear RGB, or on
#: ``u = √(max(x, 0) + SQRT_OFFSET)`` with the residual added to ``u`` and
#: the output decoded as ``u² − SQRT_OFFSET`` (negative inputs clip to 0)
ENCODINGS = ("linear", "sqrt")
SQRT_OFFSET = 1e-3
#: ``highpass_domain`` choices: the high-pass filters the residual in the
#: network's own domain (``u``), or the residual it makes in linear RGB
HIGHPASS_DOMAINS = ("encoded", "linear")


def field_features(field: Tensor, factor: int) -> Tensor:
    """Field features at ``1/factor`` resolution, (N, 2 + K, H, W) → (N, 3 +
    K, H/f, W/f).

    The mean over each ``factor × factor`` block of the coordinates (the
    block centre's position, exactly, for coordinates linear in the pixel
    index), the squared radius ``x² + y²`` (aberrations vary mostly with
    the radius), then the block mean of the ``K`` device-descriptor
    channels, if any (:func:`isp.io.device.descriptor_map`).
    """
    f = F.avg_pool2d(field, factor) if factor > 1 else field
    r2 = f[:, :1] * f[:, :1] + f[:, 1:2] * f[:, 1:2]
    if f.shape[1] == 2:   # a blind network's graph: no empty slice (export/int8_form reads its pattern)
        return torch.cat([f, r2], dim=1)
    return torch.cat([f[:, :2], r2, f[:, 2:]], dim=1)


def _zero_conv(cin: int, cout: int) -> nn.Conv2d:
    """A 1×1 conv, no bias, starting at 0 (a modulation that starts as the identity)."""
    conv = nn.Conv2d(cin, cout, 1, bias=False)
    nn.init.zeros_(conv.weight)
    return conv


def film(h: Tensor, features: Tensor, conv: nn.Conv2d, *, shift: bool = True) -> Tensor:
    """FiLM (module docstring): ``h · (1 + γ) + β`` with ``(γ, β) =
    conv(features)``, per channel and pixel; (N, C, H, W) → (N, C, H, W).

    ``conv`` is a 1×1 conv without bias of ``2C`` outputs, γ then β; with
    ``shift=False`` of ``C``, γ alone (a scale). It is computed as two
    convs, the 1 as the bias of γ's: the same function, in a graph without
    the split's slices and the separate sum, which ONNX Runtime's INT8 graph
    runs between quantised tensors (``benchmarks/correction.py --profile``).
    The channel counts are the conv's, not the tensors', so that an export
    traces constant weights.

    Example
    -------
    >>> conv = nn.Conv2d(3, 4, 1, bias=False)
    >>> h, f = torch.randn(1, 2, 5, 5), torch.randn(1, 3, 5, 5)
    >>> g, b = conv(f).chunk(2, dim=1)
    >>> torch.allclose(film(h, f, conv), h * (1 + g) + b, atol=1e-6)
    True
    """
    c = conv.out_channels // 2 if shift else conv.out_channels
    w = conv.weight
    out = h * F.conv2d(features, w[:c], torch.ones(c, dtype=w.dtype, device=w.device))
    return out + F.conv2d(features, w[c:]) if shift else out


class ConvNeXtBlock(nn.Module):
    """``x + pw₂(ReLU(pw₁(conv(x))))``, ``conv`` a DOConv or a static conv,
    depthwise or grouped; (N, C, H, W) → (N, C, H, W).

    Parameters
    ----------
    channels, expansion : int
        Width, and the MLP's hidden width ``expansion · channels``.
    conv : {"doconv", "static"}
        ``"static"``: a plain ``k × k`` conv (dilation 1, grouped as
        ``group_width`` says), the "ordinary convolution" of the paper's
        ablation.
    group_width : int
        Channels per group of ``conv``: 1 (default) is depthwise, as in
        ConvNeXt; 0 or ``channels`` a dense conv.
    kernel_size, dilations, spatial, pool, window, field_channels
        Of the DOConv (:class:`~restoration.nn.doconv.DOConv2d`).
    """

    def __init__(self, channels: int, *, expansion: int, conv: str, kernel_size: int,
                 dilations: tuple[int, ...], spatial: str, pool: str, window: int, field_channels: int,
                 group_width: int = 1, film: bool = False):
        super().__init__()
        group_width = group_width or channels
        if group_width < 1 or channels % group_width:
            raise ConfigError(f"group_width must divide the block's {channels} channels; got {group_width}")
        groups = channels // group_width
        self.dynamic = conv == "doconv"
        if self.dynamic:
            self.conv = DOConv2d(channels, channels, kernel_size, dilations, groups=groups,
                                 spatial=spatial, pool=pool, window=window, field_channels=field_channels)
        else:
            self.conv = nn.Conv2d(channels, channels, kernel_size, padding=kernel_size // 2,
                                  groups=groups, bias=False)
        self.pw1 = nn.Conv2d(channels, expansion * channels, 1)
        self.pw2 = nn.Conv2d(expansion * channels, channels, 1)
        with torch.no_grad():
            self.pw2.weight.mul_(0.1)
            self.pw2.bias.zero_()
        # FiLM: the spatial conv's output scaled and shifted per channel by the field features
        self.film = _zero_conv(field_channels, 2 * channels) if film and field_channels else None

    def forward(self, x: Tensor, field: Tensor | None = None) -> Tensor:
        h = self.conv(x, field) if self.dynamic else self.conv(x)
        if self.film is not None:
            h = film(h, field, self.film)
        return x + self.pw2(F.relu(self.pw1(h)))


class DOConvUNet(nn.Module):
    """Reduced-stage UNet with DOConv ConvNeXt blocks (module docstring).

    Parameters
    ----------
    widths : (c1, c2)
        Channels at ½ and ¼ resolution.
    depths : (d1, d2, d3)
        Blocks in the encoder (½), the bottleneck (¼) and the decoder (½).
    expansion : int
        MLP expansion of the blocks.
    conv : {"doconv", "static"}
        Spatial conv of the blocks.
    dilations : tuple of int
        Of the DOConv kernels, one per kernel.
    spatial : {"none", "tap", "frozen"}
        DOConv spatial attention (:mod:`~restoration.nn.doconv`).
    pool : {"local", "global"}
        DOConv attention statistics; ``"global"`` is ODConv's and is *not*
        tile-consistent.
    window : int
        Box side (odd) of the local attention statistics, in pixels of each
        block's resolution (×2 resp. ×4 at full resolution); 1: each pixel's
        own features (no box: the e9 default; a 7² box moves no quality
        figure, costs INT8 7 % of its time and widens the receptive
        radius by 12 px a block at ¼ resolution).
    field : bool
        Field-position encoding: input has 5 channels (RGB, x, y), else 3.
    kernel_size : int
        Of the DOConv kernels and the static convs.
    group_width : int
        Channels per group of the blocks' spatial convs: 1 (default)
        depthwise, as in ConvNeXt; 0 dense. Wider groups trade MACs for speed in
        INT8: ONNX Runtime's x86 integer kernels run a dense 3×3 conv 2.8×
        faster than float and a depthwise one 0.74× as fast (AVX-512 VNNI,
        ``python -m benchmarks.doconv_speed --yardsticks``).
    scale : {2, 4}
        Space-to-depth factor at the input: the two scales run at
        ``1/scale`` and ``1/(2·scale)`` resolution.
    encoding : {"linear", "sqrt"}
        What the network works on (:data:`ENCODINGS`).
    highpass : int
        Box side, a power of 3, in pixels at ``1/scale`` resolution, of the
        :class:`ResidualHighPass` on the residual; 0 (default): none. A
        larger box frees more of the residual's low frequencies and binds
        its level less: on the e9 default 9 (18 px at full resolution)
        beats 27 in PSNR, on flat fields and in speed (``isp eval``,
        ``benchmarks/flat_fields.py``).
    highpass_domain : {"encoded", "linear"}
        What the high-pass filters. ``"encoded"``: the residual ``r``
        added to ``u = √x``;
        it keeps the local means of ``u``, and squaring back adds ``r``'s
        local variance to the linear means (small ColorChecker patches
        moved by 1.26 ΔE00 on a 400 × 300 demo) and lifts a noisy black
        (the encoding clips negatives: a mean-0 field came out at +0.4 σ).
        ``"linear"``: the residual in linear RGB that ``r`` makes,
        ``d = (u + r)² − u² = r (r + 2u)``, exact for ``x ≥ 0``, and the
        output ``x + HP(d)``: linear local means are kept whatever ``x`` is,
        negatives included (the input passes untouched, not decoded). The
        same for ``encoding="linear"``.

    device : int
        Device-descriptor channels ``K`` after the field position (0: a
        blind network). The input keeps the field channels ``(x, y)``
        before them whatever ``field`` says; with ``field=False`` the
        network reads the descriptor alone (the no-field ablation of the
        conditioned design).

    Attributes
    ----------
    in_channels : int
        5 + K with field encoding or descriptor channels, else 3.
    fov_encoding : {"xy", "none"}
        For the ONNX metadata read by the correction stage.
    input_multiple : int
        ``H`` and ``W`` must be multiples of it (``2·scale``: 4 by default).
    config : dict
        The constructor arguments.
    """

    def __init__(self, *, widths: tuple[int, int] = (16, 64), depths: tuple[int, int, int] = (0, 4, 0),
                 expansion: int = 2, conv: str = "doconv", dilations: tuple[int, ...] = (1, 2, 3, 4),
                 spatial: str = "none", pool: str = "local", window: int = 7, field: bool = True,
                 kernel_size: int = 3, scale: int = 2, encoding: str = "linear", highpass: int = 0,
                 highpass_domain: str = "encoded", group_width: int = 1, device: int = 0,
                 film: bool = False):
        super().__init__()
        if device < 0:
            raise ConfigError(f"device must be 0, or K > 0 descriptor channels; got {device}")
        choose(encoding, ENCODINGS, "encoding")
        choose(highpass_domain, HIGHPASS_DOMAINS, "highpass_domain")
        choose(conv, CONV_KINDS, "conv")
        choose(spatial, SPATIAL_MODES, "spatial")
        choose(pool, POOL_MODES, "pool")
        if len(widths) != 2 or len(depths) != 3 or min(widths) < 1 or min(depths) < 0:
            raise ConfigError(f"widths must be 2 positive ints and depths 3 ints ≥ 0; got {widths}, {depths}")
        if scale not in (2, 4):
            raise ConfigError(f"scale must be 2 or 4; got {scale}")
        self.config = {"widths": tuple(widths), "depths": tuple(depths), "expansion": expansion,
                       "conv": conv, "dilations": tuple(dilations), "spatial": spatial, "pool": pool,
                       "window": window, "field": field, "kernel_size": kernel_size, "scale": scale,
                       "encoding": encoding, "highpass": highpass, "highpass_domain": highpass_domain,
                       "group_width": group_width, "device": device, "film": film}
        self.encoding = encoding
        # the linear residual differs from the encoded one only when there is an encoding
        self.linear_residual = bool(highpass) and highpass_domain == "linear" and encoding == "sqrt"
        self.field = field
        self.scale = scale
        self.input_multiple = 2 * scale
        self.device = int(device)
        #: the input carries the field (x, y): for the field features, or as the place the descriptor follows
        self.positional = field or self.device > 0
        self.in_channels = 5 + self.device if self.positional else 3
        self.fov_encoding = "xy" if self.positional else "none"
        nf = (FIELD_FEATURES if field else 0) + self.device
        if film and not nf:
            raise ConfigError("film modulates channels by the field features or the descriptor: it needs field=True "
                              "or device > 0")
        c1, c2 = widths
        block = {"expansion": expansion, "conv": conv, "kernel_size": kernel_size,
                 "dilations": tuple(dilations), "spatial": spatial, "pool": pool, "window": window,
                 "field_channels": nf, "group_width": group_width, "film": film}
        # space-to-depth and a 3×3 conv in one: a (3·scale)² conv of stride
        # `scale` is the same function (PixelUnshuffle + 3×3 conv, padding 1)
        # without the 6-D transpose ONNX Runtime spent 8 % of an INT8 run on
        self.stem = nn.Conv2d(3, c1, 3 * scale, stride=scale, padding=scale)
        # φ is smooth (linear and quadratic in the position): a 1×1 conv of it
        # spans what a 3×3 one would, at a ninth of the cost
        self.stem_field = nn.Conv2d(nf, c1, 1, bias=False) if nf else None
        self.stem_film = _zero_conv(nf, c1) if film and nf else None
        self.enc = nn.ModuleList(ConvNeXtBlock(c1, **block) for _ in range(depths[0]))
        self.down = nn.Conv2d(c1, c2, 2, stride=2)
        self.mid = nn.ModuleList(ConvNeXtBlock(c2, **block) for _ in range(depths[1]))
        self.up = nn.Sequential(nn.Conv2d(c2, 4 * c1, 1), nn.PixelShuffle(2))
        self.dec = nn.ModuleList(ConvNeXtBlock(c1, **block) for _ in range(depths[2]))
        self.head = nn.Sequential(nn.Conv2d(c1, 3 * scale * scale, 3, padding=1), nn.PixelShuffle(scale))
        with torch.no_grad():
            self.head[0].weight.mul_(0.1)
            self.head[0].bias.zero_()
        # on the packed residual (before PixelShuffle), so that SpaceToDepthForm, whose head
        # emits the same channels reordered, applies the same function: the filter is per channel
        self.highpass = ResidualHighPass(3 * scale * scale, highpass) if highpass else None

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (N, 5, H, W): linear camera RGB and the field ``(x, y)`` in
        [-1, 1] (N, 3, H, W without field encoding) → corrected RGB (N, 3, H, W)."""
        if not (torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()):
            self._check(x)
        s = self.scale
        return self.run(x[:, :3], x[:, 3:] if self.positional else None, self.stem, self.head[0], s,
                        highpass=self.highpass, pack=lambda u: 2 * F.pixel_unshuffle(u, s),
                        unpack=self.head[1])

    def run(self, rgb: Tensor, field: Tensor | None, stem: nn.Module, head: nn.Module, factor: int, *,
            highpass: nn.Module | None, pack: Callable[[Tensor], Tensor],
            unpack: Callable[[Tensor], Tensor]) -> Tensor:
        """The network between a given stem and head conv: the model's own
        (``forward``: full-resolution RGB, ``factor = scale``), or their
        space-to-depth forms (:class:`SpaceToDepthForm`: RGB packed to ½
        resolution, the field given there, ``factor = 1``); ``field`` is
        averaged by ``factor`` and ``2·factor`` for the two scales. The
        head conv's output is packed (``3·scale²`` channels or more), and
        ``highpass`` filters it (:class:`ResidualHighPass` of as many
        channels, or None); ``pack`` maps the encoded input to ``2u`` in the
        same packing (for the linear residual), ``unpack`` a packed residual
        back to the input's layout."""
        u0 = torch.sqrt(F.relu(rgb) + SQRT_OFFSET) if self.encoding == "sqrt" else rgb
        f1 = f2 = None
        h = stem(u0)
        if self.positional:
            f1, f2 = self.features(field, factor), self.features(field, 2 * factor)
            if self.stem_film is not None:
                h = film(h, f1, self.stem_film, shift=False)
            h = h + self.stem_field(f1)
        for b in self.enc:
            h = b(h, f1)
        skip = h
        h = self.down(h)
        for b in self.mid:
            h = b(h, f2)
        h = self.up(h) + skip
        for b in self.dec:
            h = b(h, f1)
        r = head(h)
        if self.linear_residual:  # (u + r)² − u² = r (r + 2u): no u² − c, no cancellation
            return rgb + unpack(highpass(r * (r + pack(u0))))
        u = u0 + unpack(r if highpass is None else highpass(r))
        return u * u - SQRT_OFFSET if self.encoding == "sqrt" else u

    def features(self, field: Tensor, factor: int) -> Tensor:
        """What the attention and the stem read at ``1/factor`` resolution:
        :func:`field_features`, or without ``field`` the descriptor
        channels' block means alone."""
        if self.field:
            return field_features(field, factor)
        d = field[:, 2:]
        return F.avg_pool2d(d, factor) if factor > 1 else d

    def _check(self, x: Tensor) -> None:
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            what = "RGB + field (x, y)" if self.positional else "RGB"
            what += f" + {self.device} descriptor channels" if self.device else ""
            raise ConfigError(f"expected input (N, {self.in_channels}, H, W) ({what}); got {tuple(x.shape)}")
        m = self.input_multiple
        if x.shape[2] % m or x.shape[3] % m:
            raise ConfigError(f"H and W must be multiples of {m}; got {tuple(x.shape[2:])} "
                              "(use restoration.nn.network.forward_padded)")


#: The exported head's output channels are padded to a multiple of this (zero
#: filters, sliced off: the same function). ONNX Runtime's x86 QLinearConv
#: runs output channels in blocks of 16: the packed head, 16 → 12 channels,
#: 3×3, took 11.9 % of a 1,072² tile's INT8 time with two threads, padded
#: 2.6 %, the tile 79 → 69 ms (``benchmarks/correction.py --profile``).
HEAD_CHANNEL_MULTIPLE = 16


def padded_channels(n: int, multiple: int) -> int:
    """``n`` rounded up to a multiple of ``multiple``.

    >>> padded_channels(12, 16), padded_channels(16, 16)
    (16, 16)
    """
    return -(-n // multiple) * multiple


def padded_conv(conv: nn.Conv2d, multiple: int) -> nn.Conv2d:
    """A copy of ``conv`` with its output channels padded by zero filters to
    a multiple of ``multiple``: the first ``conv.out_channels`` are the same
    function, in the shape a quantised kernel runs fast.

    Examples
    --------
    >>> conv = nn.Conv2d(4, 3, 1)
    >>> padded = padded_conv(conv, 8)
    >>> padded.out_channels, bool((padded(torch.ones(1, 4, 2, 2))[:, :3] == conv(torch.ones(1, 4, 2, 2))).all())
    (8, True)
    """
    out = nn.Conv2d(conv.in_channels, padded_channels(conv.out_channels, multiple), conv.kernel_size,
                    stride=conv.stride, padding=conv.padding, dilation=conv.dilation, groups=conv.groups,
                    bias=conv.bias is not None)
    with torch.no_grad():
        out.weight.zero_()
        out.weight[:conv.out_channels].copy_(conv.weight.detach())
        if conv.bias is not None:
            out.bias.zero_()
            out.bias[:conv.out_channels].copy_(conv.bias.detach())
    return out


class ResidualHighPass(nn.Module):
    """``r − box(r)``: a residual without its local means, (N, C, H, W) →
    (N, C, H, W).

    ``box`` is the mean over a ``window × window`` square, ``window = 3^k``,
    computed as ``k`` depthwise 3×3 means with dilations 1, 3, …, 3^(k−1)
    (their taps cover the square once each): constant weights that
    quantise to INT8 convs of the fast 3×3 kind; a 33-tap depthwise pair
    took more than half of an INT8 tile's time (``benchmarks/correction.py
    --profile`` on such an export). The residual is first extended by ``window // 2`` pixels
    replicating its edge (with zero padding the mean leans to 0 within
    ``window // 2`` of the border and a level shift gets through there), so
    a constant residual (a tone curve on a flat field) is removed exactly
    everywhere; detail at scales under ``window`` passes. A tile's own
    border is replicated too, inside the context the stage discards.

    Examples
    --------
    >>> hp = ResidualHighPass(3, 9)
    >>> float(hp(torch.full((1, 3, 20, 20), 0.2)).abs().max()) < 1e-7
    True
    """

    def __init__(self, channels: int, window: int):
        super().__init__()
        if window < 3 or 3 ** round(math.log(window, 3)) != window:
            raise ConfigError(f"highpass must be 0 (off) or a box side that is a power of 3; got {window}")
        k = round(math.log(window, 3))
        self.window = window
        self.dilations = tuple(3 ** i for i in range(k))
        self.removed: Tensor | None = None
        # persistent: exported as initializers, which INT8 quantisation needs (restoration.nn.doconv);
        # one per stage, so that each conv has its own weight to quantise
        for i in range(k):
            self.register_buffer(f"box{i}", torch.full((channels, 1, 3, 3), 1.0 / 9))

    def forward(self, r: Tensor) -> Tensor:
        p = self.window // 2
        m = F.pad(r, (p, p, p, p), mode="replicate")
        for i, d in enumerate(self.dilations):  # each shrinks the extent by 2·d; Σ 2·d = 2·p
            m = F.conv2d(m, getattr(self, f"box{i}"), dilation=d, groups=r.shape[1])
        # kept while training, for highpass_removed_power (not in eval: no graph to hold on to)
        self.removed = m if self.training and torch.is_grad_enabled() else None
        return r - m


def highpass_removed_power(model: nn.Module) -> Tensor | float:
    """Mean square of what the model's :class:`ResidualHighPass` removed in
    its last training forward (0. without one): a penalty for the loss
    (``optim.highpass_penalty``).

    Whatever the network puts into its residual's local means, the
    high-pass takes out again: a null space the output never sees. The e9
    network (linear domain) trained without the penalty uses it freely: on
    a flat 0.9 its linear residual reaches 0.2 before the high-pass, which sets the range,
    and so the step, of that tensor's INT8 quantisation. The penalty costs
    the output nothing and keeps the range for detail.
    """
    hp = getattr(model, "highpass", None)
    removed = getattr(hp, "removed", None)
    return 0.0 if removed is None else (removed * removed).mean()


class SpaceToDepthForm(nn.Module):
    """The same function as a :class:`DOConvUNet`, on its input packed
    ``s × s`` to depth (``s`` the model's ``scale``): what the export ships.

    The stem, a ``3s × 3s`` conv of stride ``s`` with padding ``s``, is
    exactly a 3×3 conv (padding 1) of the packed input; the head's conv to
    ``3s²`` channels followed by PixelShuffle is exactly its conv with the
    output channels reordered to the packing. The weights are reindexed,
    nothing is retrained; every other layer is the model's own
    (:meth:`DOConvUNet.run`). In ONNX Runtime this drops the strided stem's
    im2col and the head's DepthToSpace at full resolution (and the head's
    output channels are padded to :data:`HEAD_CHANNEL_MULTIPLE`,
    :func:`padded_conv`): on the e9 model,
    INT8 on a 1,072² tile, 0.67 → 0.60 s (FP32 1.02 → 0.99 s) on this
    project's 2-core machine; the stage packs and unpacks while it copies
    the tile anyway (:mod:`modules.common.tiling`).

    Input ``(N, 3s² [+ 2 + K], H/s, W/s)``: channel ``(dy·s + dx)·3 + c`` is
    colour ``c`` of pixel ``(s·i + dy, s·j + dx)``; then the field ``(x, y)``
    of each block's centre (the mean of its pixels' positions) and the ``K``
    descriptor channels' block means. Output
    ``(N, 3s², H/s, W/s)`` packed the same way
    (:func:`modules.correction.pack_input`, :func:`~modules.correction.unpack_output`).
    """

    def __init__(self, model: DOConvUNet):
        super().__init__()
        self.model = model
        s = self.packing = model.scale
        self.fov_encoding = model.fov_encoding
        self.input_multiple = model.input_multiple
        w, c1 = model.stem.weight.detach(), model.stem.out_channels
        self.stem = nn.Conv2d(3 * s * s, c1, 3, padding=1)
        with torch.no_grad():
            # W[o, c, s·ky + dy, s·kx + dx] → W'[o, (dy·s + dx)·3 + c, ky, kx]
            self.stem.weight.copy_(w.view(c1, 3, 3, s, 3, s).permute(0, 3, 5, 1, 2, 4).reshape(c1, 3 * s * s, 3, 3))
            self.stem.bias.copy_(model.stem.bias.detach())
        conv = model.head[0]
        # PixelShuffle reads channel c·s² + dy·s + dx; the packing wants (dy·s + dx)·3 + c
        order = [c * s * s + d for d in range(s * s) for c in range(3)]
        head = nn.Conv2d(conv.in_channels, 3 * s * s, conv.kernel_size, padding=conv.padding)
        with torch.no_grad():
            head.weight.copy_(conv.weight.detach()[order])
            head.bias.copy_(conv.bias.detach()[order])
        # the head's output channels padded, and the high-pass run on all of them: ONNX Runtime's
        # x86 INT8 convs run channels in blocks of 16 (HEAD_CHANNEL_MULTIPLE); the pad is sliced off
        self.head = padded_conv(head, HEAD_CHANNEL_MULTIPLE)
        self.channels = head.out_channels
        hp = model.highpass
        self.highpass = None if hp is None else ResidualHighPass(self.head.out_channels, hp.window)
        # 2u in the padded packing, for the linear residual: a 1×1 conv of constant weights (the
        # packed input has 3s² channels, the head's output more), which quantises with the rest
        twice = torch.zeros(self.head.out_channels, head.out_channels, 1, 1)
        twice[:head.out_channels, :, 0, 0] = 2 * torch.eye(head.out_channels)
        self.register_buffer("twice", twice)

    def forward(self, x: Tensor) -> Tensor:
        k = 3 * self.packing ** 2
        m = self.model
        return m.run(x[:, :k], x[:, k:] if m.positional else None, self.stem, self.head, 1,
                     highpass=self.highpass, pack=lambda u: F.conv2d(u, self.twice),
                     unpack=lambda y: y[:, :self.channels])


def pad_to_multiple(x: Tensor, multiple: int = 4, n_field: int = 2) -> tuple[Tensor, tuple[int, int]]:
    """Pad (N, C, H, W) at the bottom and right to multiples of ``multiple``.

    The channels are a model's input: RGB, then ``n_field`` field
    coordinates (0 or 2), then any descriptor channels. The field
    coordinates are extrapolated linearly (their step is read from the
    last two rows / columns), so the padding has the positions it would
    have on a larger frame; every other channel is padded by replicating
    the edge. Returns the padded tensor and the original ``(H, W)``.
    """
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if not (ph or pw):
        return x, (h, w)
    padded = F.pad(x, (0, pw, 0, ph), mode="replicate")
    if not n_field:
        return padded, (h, w)
    fld = x[:, 3:3 + n_field]
    for dim, p in ((3, pw), (2, ph)):
        if p:
            n = fld.shape[dim]
            last = fld.narrow(dim, n - 1, 1)
            step = last - fld.narrow(dim, n - 2, 1) if n > 1 else torch.zeros_like(last)
            k = torch.arange(1, p + 1, dtype=fld.dtype, device=fld.device)
            shape = [1, 1, 1, 1]
            shape[dim] = p
            fld = torch.cat([fld, last + step * k.view(shape)], dim=dim)
    return torch.cat([padded[:, :3], fld, padded[:, 3 + n_field:]], dim=1), (h, w)


def forward_padded(model: DOConvUNet, x: Tensor) -> Tensor:
    """``model(x)`` for any ``H, W``: pad (:func:`pad_to_multiple`), run, crop."""
    xp, (h, w) = pad_to_multiple(x, model.input_multiple, 2 if model.positional else 0)
    return model(xp)[..., :h, :w]


def receptive_radius(model: nn.Module, size: int = 256) -> int:
    """Measured receptive-field radius in input pixels: the largest
    Chebyshev distance from the centre output pixel to an input pixel whose
    gradient is non-zero, on a random ``size × size`` input (float64).

    A tile whose overlap is at least this radius on each side gives, in its
    interior, the same output as the full frame — with ``pool="local"``.
    Returns ``size // 2`` or more when the field reaches the border (e.g.
    ``pool="global"``).
    """
    m = model.double().eval()
    try:
        x = torch.rand(1, m.in_channels, size, size, dtype=torch.float64, requires_grad=True)
        c = size // 2
        m(x)[0, :, c, c].sum().backward()
        g = x.grad[0].abs().sum(0)
        ys, xs = torch.nonzero(g > 0, as_tuple=True)
        return int(torch.maximum((ys - c).abs(), (xs - c).abs()).max())
    finally:
        model.float()


# ---------------------------------------------------------------- registry

_MODELS: dict[str, Callable[..., DOConvUNet]] = {}


def register_model(fn: Callable[..., DOConvUNet]) -> Callable[..., DOConvUNet]:
    """Decorator: register a factory under its function name (timm's
    ``register_model``); re-registering a name replaces it."""
    _MODELS[fn.__name__] = fn
    return fn


def list_models() -> list[str]:
    """Registered variant names, sorted."""
    return sorted(_MODELS)


def build_model(variant: str = "doconv", **overrides) -> DOConvUNet:
    """Build a registered variant; ``overrides`` replace its
    :class:`DOConvUNet` arguments.

    >>> build_model("doconv", depths=(1, 1, 1)).config["depths"]
    (1, 1, 1)
    >>> build_model("nope")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: unknown model variant 'nope'; valid: device, ...
    """
    try:
        factory = _MODELS[variant]
    except KeyError:
        raise ConfigError(f"unknown model variant {variant!r}; valid: {', '.join(list_models())}") from None
    valid = inspect.signature(DOConvUNet).parameters
    bad = sorted(set(overrides) - set(valid))
    if bad:
        raise ConfigError(f"unknown argument(s) {', '.join(bad)} for model {variant!r}; "
                          f"valid: {', '.join(valid)}")
    return factory(**overrides)


#: the default configuration; every variant departs from it in one respect
DEFAULT = {"widths": (16, 64), "depths": (0, 4, 0), "expansion": 2, "conv": "doconv",
           "dilations": (1, 2, 3, 4), "spatial": "none", "pool": "local", "window": 7, "field": True,
           "kernel_size": 3, "scale": 2}


@register_model
def doconv(**kw) -> DOConvUNet:
    """The default: DOConv blocks, dilations 1–4, local attention with
    field features, no spatial attention (exports as constant-weight convs)."""
    return DOConvUNet(**{**DEFAULT, **kw})


@register_model
def doconv_spatial_tap(**kw) -> DOConvUNet:
    """Per-pixel spatial attention, exact, as ``k²`` shifted 1×1 convs per kernel (same MACs)."""
    return DOConvUNet(**{**DEFAULT, "spatial": "tap", **kw})


@register_model
def doconv_spatial_frozen(**kw) -> DOConvUNet:
    """Spatial attention trained per pixel, frozen to its running mean (folded
    into the weights) in eval mode and export."""
    return DOConvUNet(**{**DEFAULT, "spatial": "frozen", **kw})


@register_model
def device(**kw) -> DOConvUNet:
    """A network for every device of a design: the device's 16-number
    descriptor per field region as input channels beside the field
    (:mod:`isp.io.device`), into the stem and the attention."""
    return DOConvUNet(**{**DEFAULT, "device": 16, **kw})


@register_model
def device_attention(**kw) -> DOConvUNet:
    """As ``device``, its DOConv attention driven by field position and
    descriptor alone (no image content): for one device a fixed map."""
    return DOConvUNet(**{**DEFAULT, "device": 16, "pool": "field", **kw})


@register_model
def device_film(**kw) -> DOConvUNet:
    """As ``device``, the field and descriptor also scaling and shifting the
    stem's and every block's spatial-conv channels (FiLM; module docstring)."""
    return DOConvUNet(**{**DEFAULT, "device": 16, "film": True, **kw})


@register_model
def doconv_global(**kw) -> DOConvUNet:
    """ODConv's global-average-pool attention (per image; not tile-consistent)."""
    return DOConvUNet(**{**DEFAULT, "pool": "global", **kw})


@register_model
def equal_dilation(**kw) -> DOConvUNet:
    """Ablation: four kernels, all dilation 1."""
    return DOConvUNet(**{**DEFAULT, "dilations": (1, 1, 1, 1), **kw})


@register_model
def no_field(**kw) -> DOConvUNet:
    """Ablation: no field-position encoding (3-channel input)."""
    return DOConvUNet(**{**DEFAULT, "field": False, **kw})


@register_model
def static(**kw) -> DOConvUNet:
    """Ablation: plain depthwise convs, widths raised (c2 = 2·c1) until the
    MACs per pixel are closest to those of ``doconv`` with the same other
    arguments (unless ``widths`` is given)."""
    from restoration.nn.macs import macs_per_pixel

    if "widths" in kw:
        return DOConvUNet(**{**DEFAULT, "conv": "static", **kw})
    cfg = {**DEFAULT, **kw}
    target = macs_per_pixel(DOConvUNet(**cfg), (16, 16))

    def macs(c1):
        return macs_per_pixel(DOConvUNet(**{**cfg, "conv": "static", "widths": (c1, 2 * c1)}), (16, 16))

    # MACs grow about with the square of the width: start there, then step
    c0 = cfg["widths"][0]
    c1 = max(1, round(c0 * (target / macs(c0)) ** 0.5))
    step = 1 if macs(c1) < target else -1
    while c1 + step >= 1 and abs(macs(c1 + step) - target) < abs(macs(c1) - target):
        c1 += step
    return DOConvUNet(**{**cfg, "conv": "static", "widths": (c1, 2 * c1)})
