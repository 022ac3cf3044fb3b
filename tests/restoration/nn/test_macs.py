"""The MAC counter (restoration/nn/macs.py): it counts the DOConv
branches, which are functional convolutions.

Kind: property.
"""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")

from restoration.nn.doconv import DOConv2d
from restoration.nn.macs import count_macs


def test_macs_counter_sees_functional_convs():
    """The DOConv branches are F.conv2d calls (no nn.Conv2d module): counted."""
    layer = DOConv2d(8, 8, groups=8).eval()
    macs = count_macs(layer, torch.zeros(1, 8, 10, 10))
    assert macs["total"] - macs["attention"] == 4 * 9 * 8 * 100
