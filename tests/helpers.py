"""Where the shared data lives, for tests (``../shared/data`` beside the repo)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def data_file(*parts: str) -> Path:
    """Path of a shared data file; skips the test with the reason if absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not available: {p} (tests that use ../shared/data skip without it)")
    return p


def kernel_psf_map(kernel, *, height: int, width: int, grid=(3, 4), n: int = 16, pitch_um: float = 0.5):
    """A PSFMap on a sensor of 1-µm pixels whose PSF in region (r, c),
    channel ch (R, G, B) is ``kernel(r, c, ch, xx, yy)`` on an n×n grid of
    ``pitch_um`` offsets (µm from the centre sample), normalised to sum 1."""
    import numpy as np

    from calibration.optics.lens import Sensor
    from calibration.optics.psf.map import PSFMap, region_centers_mm

    sensor = Sensor(pixel_pitch_um=1.0, width_px=width, height_px=height)
    rows, cols = grid
    o = (np.arange(n) - n // 2) * pitch_um
    xx, yy = np.meshgrid(o, o)
    psfs = np.zeros((rows, cols, 3, n, n))
    for r in range(rows):
        for c in range(cols):
            for ch in range(3):
                g = np.asarray(kernel(r, c, ch, xx, yy), float)
                psfs[r, c, ch] = g / g.sum()
    centers = region_centers_mm(sensor, grid)
    return PSFMap(psfs, pitch_um, centers, np.zeros_like(centers), ("R", "G", "B"), sensor)


def e9_device(names, u, *, grid, noise: float, rng, n: int = 48, pupil_samples: int = 48, n_wavelengths: int = 2):
    """The e9 phone lens and its edges measured on a device perturbed by
    ``u`` (tolerance units) in ``names``: PSF map on ``grid`` (``n``
    samples, ``pupil_samples``, ``n_wavelengths``), an edge pair per
    region with ``noise`` (seeded by ``rng``). Returns (nominal lens,
    observations)."""
    import numpy as np

    from calibration.optics.io.lens_json import read_lens
    from calibration.fit.proxy import parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.optics.psf.map import psf_map

    lens = read_lens(data_file("lenses", "phone", "US-12210142-B2-e9.zmx"))
    space = parameter_space(lens, names)
    pm = psf_map(space.apply(np.asarray(u, float) * space.tolerance), grid=grid, channels=("G",), n=n,
                 pupil_samples=pupil_samples, n_wavelengths=n_wavelengths, progress=False)
    return lens, synthetic_observations(pm, noise=noise, rng=rng)
