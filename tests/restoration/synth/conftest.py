"""Fixtures of the synthesis tests (restoration/synth).

Fixtures
--------
cameras
    The colour metadata of the S6 and LG G4 phone DNGs (module-wide; a skip
    without ``../shared/data``).
"""

from __future__ import annotations

import pytest

from tests.helpers import data_file

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")
LG = ("raw", "skia_sample_1mp.dng")


@pytest.fixture(scope="module")
def cameras():
    """The colour metadata of two phone DNGs (S6, LG G4), the synthesis's cameras."""
    from restoration.synth.colour import read_camera

    return (read_camera(data_file(*S6)), read_camera(data_file(*LG)))
