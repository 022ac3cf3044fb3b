"""Shared test fixtures: where the shared data lives, and small synthetic
frames that need no data at all."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
RAW = DATA / "raw"


def data_file(*parts: str) -> Path:
    """Path of a shared data file; skips the test with the reason if absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not available: {p} (tests that use ../shared/data skip without it)")
    return p


@pytest.fixture
def raw_file():
    return lambda name: data_file("raw", name)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)

