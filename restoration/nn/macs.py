"""Cost of a network, measured: multiply–accumulates per output pixel, parameters.

MACs are counted by running the model once under a small
``TorchDispatchMode`` that sees every convolution and matrix product at the
ATen level — including the functional ``F.conv2d`` calls inside
:class:`~restoration.nn.doconv.DOConv2d`, which forward hooks on
``nn.Conv2d``/``nn.Linear`` modules would miss (module hooks only attribute
the counts to module names). Counted: convolutions (at their full kernel
size, also where a kernel has zeros) and matrix products. Not counted:
element-wise work (attention products, sigmoid, softmax, box means, adds),
which is memory-bound and shows in the timing rather than the MAC budget.
(``torch.utils.flop_counter.FlopCounterMode`` gives the same totals but
took ≈ 35× longer here.)

The export budget (``DESIGN.md``, export section): 2 cores sustain ≈
100–150 GMAC/s in INT8, so ≤ 2 s for 12 MP allows ≈ 20 kMAC per pixel.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.utils._python_dispatch import TorchDispatchMode

_aten = torch.ops.aten


def _op_macs(func, args, out) -> int:
    if func is _aten.convolution.default:
        x, w, transposed = args[0], args[1], args[6]
        # weight (C_out, C_in/g, k…) or, transposed, (C_in, C_out/g, k…)
        return (x if transposed else out).numel() * math.prod(w.shape[1:])
    if func in (_aten.mm.default, _aten.bmm.default):
        return out.numel() * args[0].shape[-1]
    if func in (_aten.addmm.default, _aten.baddbmm.default):
        return out.numel() * args[1].shape[-1]
    return 0


class _MacCounter(TorchDispatchMode):
    def __init__(self):
        super().__init__()
        self.stack: list[str] = []
        self.counts: dict[str, int] = {"total": 0}

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        n = _op_macs(func, args, out)
        if n:
            for name in ["total", *self.stack]:
                self.counts[name] = self.counts.get(name, 0) + n
        return out


def count_macs(model: nn.Module, x: torch.Tensor) -> dict[str, int]:
    """MACs of one forward pass of ``model`` on ``x``, total and per module.

    Parameters
    ----------
    model : nn.Module
        Run in its current mode (train/eval), under ``torch.no_grad``.
    x : Tensor
        The input.

    Returns
    -------
    dict
        ``"total"`` and one entry per module path (``""`` the model itself;
        nested modules are included in their parents), in MACs; modules
        without convolutions or products are absent.

    >>> count_macs(nn.Conv2d(2, 3, 3, padding=1), torch.zeros(1, 2, 4, 4))["total"]
    864
    """
    counter = _MacCounter()
    handles = []

    def enter(name):
        def hook(module, args):
            counter.stack.append(name)
        return hook

    def leave(module, args, out):
        counter.stack.pop()

    for name, mod in model.named_modules():
        handles.append(mod.register_forward_pre_hook(enter(name)))
        handles.append(mod.register_forward_hook(leave))
    try:
        with torch.no_grad(), counter:
            model(x)
    finally:
        for h in handles:
            h.remove()
    return counter.counts


def macs_per_pixel(model: nn.Module, size: tuple[int, int] = (64, 64), in_channels: int | None = None) -> float:
    """MACs per output pixel of an image-to-image ``model``, measured on a
    ``(1, C, *size)`` zero input in eval mode (what exports).

    ``C`` is ``in_channels``, else ``model.in_channels``. For a fully
    convolutional network the count per pixel does not depend on ``size``
    (pick one the model accepts).
    """
    c = in_channels if in_channels is not None else model.in_channels
    was_training = model.training
    model.eval()
    try:
        total = count_macs(model, torch.zeros(1, c, *size))["total"]
    finally:
        model.train(was_training)
    return total / (size[0] * size[1])


def n_parameters(model: nn.Module) -> int:
    """Trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
