"""The shared test fixtures: the command line, the shared data, the phone
lenses and small synthetic devices.

Fixtures
--------
cli
    ``cli(*argv)`` runs the ``isp`` command line in-process and returns
    ``(exit_code, stdout, stderr)``; arguments are passed through ``str``.
raw_file
    ``raw_file("x.dng")``: the path of a file in ``../shared/data/raw``, or
    a skip when the shared data is absent.
e9_zmx, e9_lens
    The e9 phone lens (US 12,210,142 B2, example 9): its Zemax file in
    ``../shared/data/lenses/phone`` and the lens read from it (session-wide;
    :class:`calibration.optics.lens.Lens` is frozen).
make_e9_device
    ``make_e9_device(names, u, grid=..., noise=..., rng=...)``: the e9 lens and
    the edges measured on a device perturbed by ``u`` tolerance units in
    ``names`` (see :func:`tests.helpers.e9_device`).
make_observations
    ``make_observations(n, meta)``: ``n`` identical edges at one field
    site of a 2000 × 1500 sensor of 2-µm pixels, with measurement ``meta``.
rng
    A seeded numpy generator.

Plain functions that test modules import (``data_file``,
``kernel_psf_map``) are in :mod:`tests.helpers`.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from tests import helpers
from tests.helpers import data_file


@pytest.fixture
def cli(capsys):
    """``cli(*argv)`` → ``(exit_code, stdout, stderr)`` of ``isp *argv``, run in-process."""
    from isp.cli.main import main

    def run(*argv):
        code = main([str(a) for a in argv])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


@pytest.fixture
def raw_file():
    """``raw_file("x.dng")`` → path in ../shared/data/raw, or a skip."""
    return lambda name: data_file("raw", name)


@pytest.fixture(scope="session")
def e9_zmx():
    """Path of the e9 phone lens's Zemax file (or a skip without the shared data)."""
    return data_file("lenses", "phone", "US-12210142-B2-e9.zmx")


@pytest.fixture(scope="session")
def e9_lens(e9_zmx):
    """The e9 phone lens, read once per session."""
    from calibration.optics.io import read_lens

    return read_lens(e9_zmx)


@pytest.fixture(scope="session")
def make_e9_device():
    """The factory :func:`tests.helpers.e9_device` (a perturbed e9 device and its edges)."""
    return helpers.e9_device


@pytest.fixture(scope="session")
def make_observations():
    """The factory :func:`tests.helpers.one_site_observations`."""
    return helpers.one_site_observations


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def user_folder(tmp_path):
    """An empty user profile folder as ``$ISP_PROFILES``, the registry
    re-read (so a profile of the machine's user cannot change what a test
    sees); afterwards the environment and the registry as they were."""
    from isp.profiles import ENV_VAR, reload_profiles

    folder = tmp_path / "profiles"
    folder.mkdir()
    old = os.environ.get(ENV_VAR)
    os.environ[ENV_VAR] = str(folder)
    reload_profiles()
    yield folder
    if old is None:
        os.environ.pop(ENV_VAR, None)
    else:
        os.environ[ENV_VAR] = old
    reload_profiles()
