"""The benchmarks that run a peer beside ours (benchmarks/raytrace.py,
benchmarks/psf.py) leave it out with the reason where it is not installed
(kind: property)."""

import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.property


@pytest.mark.parametrize("module, fn", [("benchmarks.raytrace", "optiland_trace"), ("benchmarks.psf", "optiland_psfs")])
def test_an_absent_peer_is_reported_with_how_to_install_it(monkeypatch, module, fn):
    monkeypatch.setitem(sys.modules, "optiland", None)   # import optiland.… now fails as if not installed
    mod = __import__(module, fromlist=[fn])
    out = getattr(mod, fn)(Path("no.zmx"), 10, 1)
    assert out["available"] is False
    assert "pip install -e .[bench]" in out["reason"]
