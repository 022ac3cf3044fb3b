"""Shared test fixtures: the shared data, and a seeded random generator."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import data_file


@pytest.fixture
def raw_file():
    """``raw_file("x.dng")`` → path in ../shared/data/raw, or a skip."""
    return lambda name: data_file("raw", name)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
