"""A device's calibration (``device/v1``) and the descriptor a shared
correction model reads.

On a production line every camera module is measured on its chart, and
:func:`calibration.fit.proxy.fit_proxy` turns that measurement into a proxy
lens: the design plus the perturbation that reproduces the device's SFR.
One shared correction network cannot read a lens prescription; it reads a
short vector per field region, the device's **descriptor**, and this module
makes it.

The descriptor
--------------
The PSF of a lens drawn within tolerance differs from the design's mean PSF
in a few correlated ways (defocus, astigmatism and coma growing over the
field, lateral colour), so the differences are well described by few
principal components. A :class:`DescriptorBasis` is learned once per lens
design (:func:`learn_basis`) from the PSF maps of many lenses drawn within
tolerance (:func:`calibration.simulate.device.draw_lenses`, refocused as
assembly does):

1. each lens's PSF map on a coarse grid of field regions (default 5 × 7),
   integrated over the pixel cells (:func:`pixel_psfs`), R, G and B;
2. the mean over the draws of each region's PSFs, ``μ_r``;
3. per region, the principal components of the deviations ``h − μ_r``
   over the draws, the three channels as one vector (so a component holds
   a colour's shift as well as its blur): the region's best
   ``K``-dimensional span;
4. each region's span rotated (orthogonal Procrustes) onto the principal
   directions pooled over all regions, ``V_{r,k}``, so that channel ``k``
   of the descriptor means nearly the same change of the PSF in every
   region and interpolating it between regions means something (a region's
   own PCA has arbitrary signs and order); ``s_{r,k}`` the spread of its
   coefficient over the draws.

A device's descriptor is then, per region ``r`` and component ``k``,

.. math::

    d_{r,k} = \\frac{\\langle h_r - \\mu_r, V_{r,k}\\rangle}{s_{r,k}},

dimensionless, of unit spread over the tolerance distribution (what a
network input wants), and its PSFs are recovered as ``μ_r + Σ_k d_{r,k}
s_{r,k} V_{r,k}`` (:meth:`DescriptorBasis.reconstruct`). The rotation
leaves each region's span, so what it reconstructs, unchanged. How many
components are worth keeping, against one basis pooled over the regions and
against MTF samples, is measured in ``benchmarks/device_descriptor.py``.

The file
--------
``device/v1`` is JSON (:class:`isp.io.device.DeviceCalibration`, where its
keys are listed; the correction stage reads it): the lens design's name
and key, the basis's key, the grid, the descriptor (rows × cols × K numbers,
4 significant digits), the loop's kept effects, the fit's errors, and where
the measurement came from. It is at most :data:`MAX_BYTES` (64 KB; a 5 × 7
grid with 16 components is about 5 KB).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from isp.errors import InputError
from isp.io.device import FORMAT, MAX_BYTES, DeviceCalibration

__all__ = ["BASIS_FORMAT", "BASIS_WORDS", "DEFAULT_COMPONENTS", "DEFAULT_GRID", "DescriptorBasis", "DeviceCalibration",
           "FORMAT", "MAX_BYTES", "basis_from_psfs", "check_calibration", "describe", "descriptor_map_settings", "design_key",
           "device_calibration", "find_basis", "learn_basis", "load_basis", "measurement_source", "pixel_psfs",
           "psf_stack", "resolve_basis"]

#: schema of the basis file (numpy ``.npz``)
BASIS_FORMAT = "device-basis/v1"
#: how a basis file stores its components and mean PSFs (compressed): half precision keeps a
#: component's unit-norm entries (about 0.02 each) to 1e-3 of themselves, and the e9 basis the
#: packaged conditioned model reads (5 × 7 regions, 16 components, 3 × 32² px PSFs) to 3.7 MB
#: where single precision took 7.7 MB; a descriptor moves by at most 1e-3 of a spread (RMS 2e-4)
COMPONENT_DTYPE = np.float16
MEAN_DTYPE = np.float32
#: field regions of the descriptor (rows, cols): the fit's chart grid on a 4:3 sensor
DEFAULT_GRID = (5, 7)
#: components kept in a device file
DEFAULT_COMPONENTS = 16


def design_key(lens) -> str:
    """SHA-256 (hex) of a lens *design*: the nominal prescription of a Lens
    or PerturbedLens, whatever its perturbation, name, metadata or sensor
    (a capture's crop changes the sensor a fit sees, not the optics).
    Device files, bases and models of one design share it."""
    import dataclasses

    from calibration.optics.perturb import nominal
    from calibration.optics.psf.map import canonical

    design = nominal(lens).nominal
    doc = {f.name: canonical(getattr(design, f.name)) for f in dataclasses.fields(design)
           if f.name not in ("name", "metadata", "sensor")}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def pixel_psfs(psfmap) -> np.ndarray:
    """The map's PSFs integrated over the pixel cells: ``(rows, cols,
    channels, m, m)`` float64, ``m = n / f`` with ``f`` the pixel pitch over
    the PSF's sample pitch (an integer: psf_map's default samples half a
    pixel, ``f = 2``). Each sums to what its window holds (≤ 1).

    >>> from calibration.optics.lens import Sensor
    >>> from calibration.optics.psf.map import PSFMap
    >>> m = PSFMap(np.full((1, 1, 1, 4, 4), 1 / 16), 0.5, np.zeros((1, 1, 2)), np.zeros((1, 1, 2)),
    ...            ("G",), Sensor(1.0, 10, 10))
    >>> pixel_psfs(m)[0, 0, 0]
    array([[0.25, 0.25],
           [0.25, 0.25]])
    """
    f = psfmap.sensor.pixel_pitch_um / psfmap.pitch_um
    fi = int(round(f))
    if fi < 1 or abs(f - fi) > 1e-9 or psfmap.n % fi:
        raise ValueError(f"the PSF pitch {psfmap.pitch_um} µm does not divide the pixel pitch "
                         f"{psfmap.sensor.pixel_pitch_um} µm into the map's {psfmap.n} samples")
    r, c, ch, n, _ = psfmap.psfs.shape
    m = n // fi
    return psfmap.psfs.astype(np.float64).reshape(r, c, ch, m, fi, m, fi).sum(axis=(4, 6))


def descriptor_map_settings(grid, channels=("R", "G", "B")):
    """The PSF map settings of a descriptor: psf_map's defaults on ``grid``."""
    from calibration.optics.psf.map import PSFMapSettings

    return PSFMapSettings(grid=tuple(grid), channels=tuple(channels))


def psf_stack(lenses, grid=DEFAULT_GRID, *, sensor=None, executor=None, cache_dir=None,
              progress: bool = False) -> np.ndarray:
    """Pixel PSFs ``(lenses, rows, cols, 3, m, m)`` of lenses on a
    descriptor's grid (:func:`pixel_psfs` of each cached PSF map; ``sensor``
    default each lens's own)."""
    from tqdm import tqdm

    from calibration.optics.psf.map import psf_map

    settings = descriptor_map_settings(grid)
    return np.stack([pixel_psfs(psf_map(pl, settings, sensor=sensor, cache_dir=cache_dir, executor=executor))
                     for pl in tqdm(lenses, desc="PSF maps of drawn lenses", unit="lens", disable=not progress)])


@dataclass(frozen=True)
class DescriptorBasis:
    """Principal components of a lens design's PSFs over its tolerances
    (module docstring). Built by :func:`learn_basis`; files by
    :meth:`save` / :meth:`load`.

    Attributes
    ----------
    lens : str
        The design's name.
    design : str
        :func:`design_key` of the design.
    grid : (rows, cols)
    channels : tuple of str
    mean : (rows, cols, channels, m, m) float64
        Each region's mean pixel PSF over the draws.
    components : (rows, cols, K, channels·m·m) float64
        Each region's directions, orthonormal (stored in half precision,
        :data:`COMPONENT_DTYPE`; the mean in single).
    scales : (rows, cols, K) float64
        Spread (standard deviation) of each coefficient over the draws.
    explained : (K,) float64
        Fraction of the deviations' variance the first ``k + 1`` components
        hold, over all regions.
    draws : int
        Lenses the basis was learned from.
    sensor : Sensor
        The sensor whose regions and pixels the PSFs are mapped on: a
        device's descriptor is computed on it whatever sensor its capture
        had (:func:`describe`).
    meta : dict
        Tolerance scale, seed, PSF settings (JSON-safe).
    """

    lens: str
    design: str
    grid: tuple[int, int]
    channels: tuple[str, ...]
    mean: np.ndarray
    components: np.ndarray
    scales: np.ndarray
    explained: np.ndarray
    draws: int
    sensor: object = None
    meta: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        """SHA-256 (hex) of the basis's numbers: a device file names the basis it was made with."""
        h = hashlib.sha256()
        for a in (self.mean, self.components, self.scales):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
        h.update(json.dumps([self.design, list(self.grid), list(self.channels), self._sensor_dict()]).encode())
        return h.hexdigest()

    def _sensor_dict(self) -> dict | None:
        import dataclasses

        return dataclasses.asdict(self.sensor) if self.sensor is not None else None

    @property
    def size(self) -> int:
        """Components held per region (K)."""
        return self.components.shape[2]

    def project(self, psfs: np.ndarray, k: int | None = None) -> np.ndarray:
        """The descriptor of pixel PSFs ``(rows, cols, channels, m, m)``
        (:func:`pixel_psfs` of a map on this basis's grid): ``(rows, cols,
        k)`` float64, each number of unit spread over the tolerances (the
        first ``k`` components; all by default)."""
        psfs = np.asarray(psfs, dtype=np.float64)
        if psfs.shape != self.mean.shape:
            raise ValueError(f"PSFs of shape {psfs.shape}; this basis takes {self.mean.shape}")
        k = self.size if k is None else int(k)
        if not 1 <= k <= self.size:
            raise ValueError(f"k must be between 1 and {self.size}, got {k}")
        r, c = self.grid
        dev = (psfs - self.mean).reshape(r, c, -1)
        return np.einsum("rcd,rckd->rck", dev, self.components[:, :, :k]) / self.scales[:, :, :k]

    def reconstruct(self, descriptor: np.ndarray) -> np.ndarray:
        """Pixel PSFs ``(rows, cols, channels, m, m)`` from a descriptor
        ``(rows, cols, k)``: each region's mean plus its first ``k`` components."""
        d = np.asarray(descriptor, dtype=np.float64)
        r, c = self.grid
        if d.ndim != 3 or d.shape[:2] != (r, c) or not 1 <= d.shape[2] <= self.size:
            raise ValueError(f"descriptor of shape {d.shape}; this basis takes ({r}, {c}, ≤ {self.size})")
        k = d.shape[2]
        dev = np.einsum("rck,rckd->rcd", d * self.scales[:, :, :k], self.components[:, :, :k])
        return self.mean + dev.reshape(self.mean.shape)

    def save(self, path) -> Path:
        """Write the basis (``.npz``, atomically); returns the path."""
        from calibration.report import write_npz

        meta = {"format": BASIS_FORMAT, "lens": self.lens, "design": self.design, "grid": list(self.grid),
                "channels": list(self.channels), "draws": self.draws, "sensor": self._sensor_dict(),
                "meta": self.meta}
        return write_npz(path, {"mean": self.mean.astype(MEAN_DTYPE),
                                "components": self.components.astype(COMPONENT_DTYPE),
                                "scales": self.scales, "explained": self.explained,
                                "info": np.array(json.dumps(meta))}, compressed=True)

    @classmethod
    def load(cls, path) -> DescriptorBasis:
        """Read a basis written by :meth:`save`; InputError naming the file otherwise."""
        p = Path(path)
        from calibration.optics.lens import Sensor

        try:
            with np.load(p, allow_pickle=False) as z:
                info = json.loads(str(z["info"]))
                if info.get("format") != BASIS_FORMAT:
                    raise InputError(p, f"not a {BASIS_FORMAT} file (format {info.get('format')!r})")
                sensor = Sensor(**info["sensor"]) if info.get("sensor") else None
                return cls(info["lens"], info["design"], tuple(info["grid"]), tuple(info["channels"]),
                           z["mean"].astype(np.float64), z["components"].astype(np.float64), z["scales"],
                           z["explained"],
                           int(info["draws"]), sensor, info.get("meta", {}))
        except FileNotFoundError:
            raise InputError(p, "no such basis file") from None
        except (OSError, ValueError, KeyError) as e:
            raise InputError(p, f"not a {BASIS_FORMAT} file ({type(e).__name__}: {str(e)[:80]})") from None


def load_basis(path, lens=None) -> DescriptorBasis:
    """Read a basis file; with ``lens``, also check that it is of that
    lens's design (InputError naming the file and both designs otherwise)."""
    basis = DescriptorBasis.load(path)
    if lens is not None and basis.design != design_key(lens):
        from calibration.optics.perturb import nominal

        name = nominal(lens).nominal.name or "this lens"
        raise InputError(path, f"a basis of lens {basis.lens!r}, not of {name!r} (another design)")
    return basis


#: ``--basis`` words that name no file: the profile's basis for the design, or none
BASIS_WORDS = ("auto", "none")


def resolve_basis(value, lens) -> DescriptorBasis | None:
    """The basis a fit of ``lens`` writes its ``device.json`` on: ``value``
    a basis file (checked to be of the lens's design, :func:`load_basis`),
    ``"none"`` for none, or ``"auto"`` (or None) for the basis a registered
    lens profile ships for the lens's design (:func:`find_basis`), none
    where no profile does."""
    key = "auto" if value is None else str(value).lower()
    if key == "none":
        return None
    if key == "auto":
        found = find_basis(lens)
        return None if found is None else load_basis(found, lens)
    return load_basis(value, lens)


def find_basis(lens) -> Path | None:
    """The basis file of ``lens``'s design that a registered lens profile
    names (:mod:`isp.profiles`, a profile's ``basis``), or None: the packaged
    e9 profile ships the basis its conditioned model was trained on, so a
    fit of an e9 module writes the calibration that model reads."""
    from isp.profiles import list_profiles

    want = design_key(lens)
    for prof in list_profiles().values():
        if prof.basis is not None and _basis_design(prof.basis) == want:
            return prof.basis
    return None


def _basis_design(path) -> str | None:
    """The design key a basis file names, read from its header alone; None
    for a file that is not a basis."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z["info"])).get("design")
    except (OSError, ValueError, KeyError):
        return None


def learn_basis(lens, draws: int = 150, *, seed: int = 0, grid: tuple[int, int] = DEFAULT_GRID,
                components: int = DEFAULT_COMPONENTS, tolerance_scale: float = 1.0, executor=None,
                cache_dir=None, progress: bool = False, name: str | None = None) -> DescriptorBasis:
    """Learn a design's descriptor basis from lenses drawn within tolerance.

    Parameters
    ----------
    lens : Lens or PerturbedLens
        The design (its perturbation, if any, is the centre of the draws).
    draws : int
        Lenses drawn (≥ 2 × ``components`` is sensible; each costs one PSF
        map of ``grid``, ≈ 7 s for e9's 5 × 7 on one core, cached on disk).
    seed : int
        Of the draws.
    grid : (rows, cols)
    components : int
        Principal components kept per region (K).
    tolerance_scale : float
        Multiplies every tolerance.
    executor : isp.runtime.executor.Executor, optional
        Runs each map's regions (psf_map's default otherwise).
    cache_dir : path, optional
        PSF map cache (psf_map's default otherwise).
    progress : bool
        A bar over the draws on stderr.
    name : str, optional
        The design's name in the files (default the lens's own; the command
        line gives the lens file's stem, what lens profiles match).

    Returns
    -------
    DescriptorBasis
    """
    from calibration.optics.perturb import nominal
    from calibration.simulate.device import draw_lenses

    if draws < 2:
        raise ValueError(f"draws must be ≥ 2, got {draws}")
    pl = nominal(lens)
    lenses = draw_lenses(pl, int(draws) + 1, np.random.default_rng(seed), tolerance_scale=tolerance_scale)[1:]
    settings = descriptor_map_settings(grid)
    stack = psf_stack(lenses, grid, executor=executor, cache_dir=cache_dir, progress=progress)
    return basis_from_psfs(stack, lens=name or pl.nominal.name or "lens", design=design_key(pl), grid=grid,
                           channels=settings.channels, components=components, sensor=pl.lens.sensor,
                           meta={"tolerance_scale": tolerance_scale, "seed": seed, "psf": settings.__dict__})


def basis_from_psfs(stack: np.ndarray, *, lens: str, design: str, grid, channels, components: int = 16,
                    sensor=None, meta: dict | None = None) -> DescriptorBasis:
    """The basis of a stack of pixel PSF maps ``(draws, rows, cols,
    channels, m, m)`` (:func:`learn_basis` without the optics): per region,
    the top ``components`` principal directions of the deviations, rotated
    within their span onto the pooled directions (module docstring)."""
    stack = np.asarray(stack, dtype=np.float64)
    n, rows, cols = stack.shape[:3]
    k = int(components)
    if not 1 <= k <= n - 1:
        raise ValueError(f"components must be between 1 and draws − 1 = {n - 1}, got {k}")
    mean = stack.mean(axis=0)
    dev = (stack - mean).reshape(n, rows, cols, -1)
    _, _, pooled = np.linalg.svd(dev.reshape(n * rows * cols, -1), full_matrices=False)
    pooled = pooled[:k]
    comps = np.empty((rows, cols, k, dev.shape[-1]))
    for r in range(rows):
        for c in range(cols):
            _, _, v = np.linalg.svd(dev[:, r, c], full_matrices=False)
            v = v[:k]
            # orthogonal Procrustes: the rotation of the region's span closest to the pooled directions
            u, _, wt = np.linalg.svd(pooled @ v.T)
            comps[r, c] = (u @ wt) @ v
    comps = comps.astype(COMPONENT_DTYPE).astype(np.float64)     # as the file stores them: the same basis, the same key
    mean = mean.astype(MEAN_DTYPE).astype(np.float64)
    coef = np.einsum("nrcd,rckd->nrck", dev, comps)
    var = coef.var(axis=0)                                         # (rows, cols, k)
    total = dev.var(axis=0).sum()
    explained = np.cumsum(var.sum(axis=(0, 1))) / total
    scales = np.sqrt(np.maximum(var, 1e-30))
    return DescriptorBasis(lens, design, tuple(int(v) for v in grid), tuple(channels), mean, comps, scales,
                           explained, n, sensor, dict(meta or {}))


def describe(lens, basis: DescriptorBasis, k: int | None = None, *, executor=None, cache_dir=None) -> np.ndarray:
    """The descriptor ``(rows, cols, k)`` of a (fitted or true) lens of the
    basis's design, its PSFs mapped on the basis's sensor; ValueError where
    the lens is of another design."""
    from calibration.optics.psf.map import psf_map

    if design_key(lens) != basis.design:
        raise ValueError(f"the lens is not of the design {basis.lens!r} this basis was learned for")
    m = psf_map(lens, descriptor_map_settings(basis.grid, basis.channels), sensor=basis.sensor, cache_dir=cache_dir,
                executor=executor)
    return basis.project(pixel_psfs(m), k)


def check_calibration(cal: DeviceCalibration, basis: DescriptorBasis) -> None:
    """ValueError (one line) where a device file was not made with ``basis``."""
    if cal.design != basis.design:
        raise ValueError(f"device calibration of lens {cal.lens!r}, basis of lens {basis.lens!r}: "
                         "another lens design")
    if cal.basis != basis.key:
        raise ValueError(f"device calibration made with another basis of {cal.lens!r} "
                         f"({cal.basis[:12]}…, this one {basis.key[:12]}…)")
    if cal.grid != basis.grid or cal.descriptor.shape[2] > basis.size:
        raise ValueError(f"descriptor {cal.descriptor.shape} does not fit the basis "
                         f"({basis.grid}, {basis.size} components)")


def measurement_source(path) -> dict:
    """A device file's ``source`` for a measurement: its file name, its
    SHA-256 where it is a file, and the module's serial number where the
    capture names one (a DNG's CameraSerialNumber: the correction stage
    refuses the file for a capture of another module)."""
    from isp.io.files import file_sha256
    from isp.io.read import camera_serial

    p = Path(path)
    serial = camera_serial(p)
    return {"measured": p.name, **({"sha256": file_sha256(p)} if p.is_file() else {}),
            **({"serial": serial} if serial else {})}


def device_calibration(proxy, basis: DescriptorBasis, k: int = DEFAULT_COMPONENTS, *, fit: dict | None = None,
                       effects=(), source: dict | None = None, executor=None, cache_dir=None) -> DeviceCalibration:
    """The ``device/v1`` calibration of a fitted proxy lens (its descriptor
    on ``basis``), with the fit's summary and the loop's kept effects."""
    from calibration.optics.perturb import nominal

    pl = nominal(proxy)
    src = dict(source or {})
    src.setdefault("perturbation", {k_: float(v) for k_, v in pl.perturbation.as_dict().items() if v != 0.0})
    return DeviceCalibration(basis.lens, basis.design, basis.key,
                             describe(pl, basis, k, executor=executor, cache_dir=cache_dir),
                             tuple(effects), dict(fit or {}), src)
