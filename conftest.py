"""Root pytest configuration (covers the doctests in the packages too)."""

import numpy as np
import pytest


@pytest.fixture(autouse=True)
def _numpy_print_style():
    """colour-science sets numpy's legacy 1.13 print style on import; doctests
    that print arrays need the current one whatever was imported first."""
    np.set_printoptions(legacy=False)
    yield
