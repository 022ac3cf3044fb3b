"""The ``device/v1`` file: one camera module's calibration, as the
correction stage reads it.

On a production line every module is measured on its chart; the fit of
that measurement (``isp calib fit --basis``, :mod:`calibration.fit.device`)
reduces the module's lens to a short *descriptor* per field region: the
coordinates of its PSFs on the principal components of its design's PSFs
over the tolerances, each of unit spread over those tolerances. A shared
correction model trained on many such lenses reads the descriptor beside
the field position (:func:`descriptor_map`), so one model corrects every
module of the design and nothing is trained per module.

The file is JSON, at most :data:`MAX_BYTES`:

==============  ==============================================================
key             value
==============  ==============================================================
``format``      ``"device/v1"``
``lens``        the design's name (the lens profile's LensModel)
``design``      SHA-256 of the design's prescription (``calibration.fit.device.design_key``)
``basis``       SHA-256 of the basis the descriptor is on
``grid``        ``[rows, cols]`` of equal field regions over the sensor
``components``  K, numbers per region
``descriptor``  ``rows × cols × K`` numbers, 4 significant digits
``effects``     the loop's kept effects, ``{"name", "params"}`` each (may be empty)
``fit``         the fit's errors (SFRA RMS before and after, χ² per observation)
``source``      the measurement (file name, SHA-256, and ``serial``: the module's serial
                number where the chart capture names one) and the fitted perturbation
==============  ==============================================================

This module reads and writes the file and interpolates the descriptor over
the frame; making one (the basis, the PSF maps) is the calibration
toolkit's.

In a DNG
--------
A capture may carry its module's calibration itself, so that the file
alone is corrected right: the project's DNG writer stores the JSON in the
``DNGPrivateData`` tag (50740, DNG 1.7 §"DNGPrivateData": private data
starting with a NUL-terminated ASCII name whose first part is the maker's)
as ``b"phone-isp device/v1\\0"`` followed by the file's UTF-8 bytes
(:func:`private_data`, :func:`from_private_data`); the reader puts it in
``CameraMeta.device_calibration``, and the correction stage uses it when it
is given no ``--device``. The whole calibration travels, not a path to it: a
capture copied elsewhere stays correctable.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from isp.errors import InputError
from isp.io.files import write_bytes_atomic

__all__ = ["DIGITS", "FORMAT", "MAX_BYTES", "PRIVATE_DATA_NAME", "DeviceCalibration", "descriptor_map",
           "from_private_data", "private_data", "rounded"]

#: schema of the file
FORMAT = "device/v1"
#: the largest file written or read, bytes
MAX_BYTES = 64 * 1024
#: significant digits of the descriptor (unit-spread numbers: 1e-4 of their spread)
DIGITS = 4
#: the NUL-terminated name that starts this project's DNGPrivateData
PRIVATE_DATA_NAME = b"phone-isp device/v1\0"


def rounded(descriptor) -> list:
    """A descriptor as the file holds it: nested lists of numbers to
    :data:`DIGITS` significant digits.

    >>> rounded(np.array([[[0.123456, -12.3456]]]))
    [[[0.1235, -12.35]]]
    """
    return np.vectorize(lambda v: float(f"{v:.{DIGITS}g}"))(np.asarray(descriptor, dtype=np.float64)).tolist()


def private_data(text: str) -> bytes:
    """DNGPrivateData bytes carrying a ``device/v1`` file's text."""
    return PRIVATE_DATA_NAME + text.encode()


def from_private_data(data) -> str:
    """The ``device/v1`` text of DNGPrivateData bytes, or "" where the data
    is another maker's (or absent)."""
    if data is None:
        return ""
    b = bytes(data) if not isinstance(data, bytes) else data
    return b[len(PRIVATE_DATA_NAME):].decode("utf-8", "replace") if b.startswith(PRIVATE_DATA_NAME) else ""


def descriptor_map(descriptor: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                   full_size: tuple[int, int]) -> np.ndarray:
    """A per-region descriptor interpolated to pixels of the full frame.

    Parameters
    ----------
    descriptor : (R, C, K) array
        One K-vector per region of an ``R × C`` grid of equal regions over
        the frame.
    rows, cols : (h,), (w,) arrays
        Row and column of each pixel (or block centre: fractional) in the
        full frame.
    full_size : (H, W)

    Returns
    -------
    (K, h, w) float32: bilinear between the region centres, constant past
    the outermost ones. Pixel ``i`` of ``N`` sits at grid coordinate
    ``(i + ½)·R/N − ½``, so this equals torch's ``grid_sample(...,
    align_corners=False, padding_mode="border")`` at the field position
    :func:`modules.correction.field_coordinates_at` gives the pixel (the
    network's twin, tested).

    >>> d = np.arange(2.0).reshape(1, 2, 1)            # two regions side by side: 0, 1
    >>> descriptor_map(d, np.array([0]), np.array([0, 1, 2, 3]), (1, 4))[0]
    array([[0.  , 0.25, 0.75, 1.  ]], dtype=float32)
    """
    d = np.asarray(descriptor, dtype=np.float64)
    if d.ndim != 3:
        raise ValueError(f"descriptor must be (rows, cols, K), got shape {d.shape}")
    R, C, _ = d.shape
    H, W = full_size

    def axis(idx, n, m):
        g = np.clip((np.asarray(idx, dtype=np.float64) + 0.5) * m / n - 0.5, 0.0, m - 1)
        i0 = np.minimum(np.floor(g).astype(np.intp), max(m - 2, 0))
        t = g - i0 if m > 1 else np.zeros_like(g)
        return i0, np.minimum(i0 + 1, m - 1), t

    r0, r1, ty = axis(rows, H, R)
    c0, c1, tx = axis(cols, W, C)
    top = d[r0][:, c0] * (1 - tx)[None, :, None] + d[r0][:, c1] * tx[None, :, None]
    bottom = d[r1][:, c0] * (1 - tx)[None, :, None] + d[r1][:, c1] * tx[None, :, None]
    out = top * (1 - ty)[:, None, None] + bottom * ty[:, None, None]
    return np.ascontiguousarray(out.transpose(2, 0, 1), dtype=np.float32)


@dataclass(frozen=True)
class DeviceCalibration:
    """One device's calibration, the ``device/v1`` file (module docstring).

    Attributes
    ----------
    lens : str
        The design's name (the lens profile's LensModel).
    design : str
        :func:`design_key`.
    basis : str
        :attr:`DescriptorBasis.key` of the basis the descriptor is on.
    descriptor : (rows, cols, k) ndarray
    effects : tuple of dict
        The loop's kept effects (``{"name", "params"}``), empty from a fit alone.
    fit : dict
        The fit's summary (SFRA RMS before/after, χ² per observation, noise floor).
    source : dict
        The measurement (file name, SHA-256) and the proxy's perturbation.
    """

    lens: str
    design: str
    basis: str
    descriptor: np.ndarray
    effects: tuple = ()
    fit: dict = field(default_factory=dict)
    source: dict = field(default_factory=dict)

    def __post_init__(self):
        d = np.asarray(self.descriptor, dtype=np.float64)
        if d.ndim != 3 or min(d.shape) < 1 or not np.all(np.isfinite(d)):
            raise ValueError(f"descriptor must be a finite (rows, cols, k) array, got shape {d.shape}")
        object.__setattr__(self, "descriptor", d)
        object.__setattr__(self, "effects", tuple(self.effects))

    @property
    def serial(self) -> str:
        """The module's serial number, from its chart capture ("" where the
        capture named none)."""
        return str(self.source.get("serial", "") or "")

    def check_module(self, serial: str, name: str, where) -> None:
        """InputError (one line, naming ``where``: the capture) where this
        calibration, read from ``name``, is another module's than the
        capture's of serial number ``serial``; nothing where either names
        no serial."""
        if self.serial and serial and self.serial != serial:
            raise InputError(where, f"{name} is the calibration of module {self.serial}, this capture is module "
                                    f"{serial}'s (CameraSerialNumber): give its own calibration, or --device none")

    @property
    def grid(self) -> tuple[int, int]:
        """(rows, cols) of field regions."""
        return self.descriptor.shape[0], self.descriptor.shape[1]

    @property
    def components(self) -> int:
        """Numbers per region (K)."""
        return self.descriptor.shape[2]

    def field_map(self, rows: np.ndarray, cols: np.ndarray, full_size: tuple[int, int]) -> np.ndarray:
        """The descriptor at pixels ``rows × cols`` of a full frame:
        ``(K, h, w)`` float32 (:func:`descriptor_map`)."""
        return descriptor_map(self.descriptor, rows, cols, full_size)

    def check_model(self, meta: dict, k: int, name: str, model: str = "the model") -> None:
        """ConfigError (one line, starting with ``name``) where a model of
        metadata ``meta`` (``device_design``, ``device_basis``, ``lens``)
        reading ``k`` descriptor channels cannot read this calibration:
        another lens design, another basis, too few components."""
        from isp.errors import ConfigError

        for key, what, kind in (("device_design", self.design, "lens design"),
                                ("device_basis", self.basis, "descriptor basis")):
            if meta.get(key) and meta[key] != what:
                raise ConfigError(f"{name}: a calibration of another {kind} than {model}'s "
                                  f"(device lens {self.lens!r}, model lens {meta.get('lens', '?')!r})")
        if self.components < k:
            raise ConfigError(f"{name}: {self.components} descriptor components; {model} reads {k}")

    def to_text(self) -> str:
        """The file's JSON text (compact)."""
        return json.dumps(self.to_dict(), separators=(",", ":"))

    def to_dict(self) -> dict:
        return {"format": FORMAT, "lens": self.lens, "design": self.design, "basis": self.basis,
                "grid": list(self.grid), "components": self.descriptor.shape[2],
                "descriptor": rounded(self.descriptor),
                "effects": list(self.effects), "fit": self.fit, "source": self.source}

    def save(self, path) -> Path:
        """Write the file atomically (ValueError above :data:`MAX_BYTES`)."""
        text = self.to_text().encode()
        if len(text) > MAX_BYTES:
            raise ValueError(f"a {FORMAT} file of {len(text)} bytes exceeds {MAX_BYTES}: fewer components "
                             "or a coarser grid")
        return write_bytes_atomic(Path(path), text)

    @classmethod
    def load(cls, path) -> DeviceCalibration:
        """Read and check a ``device/v1`` file; InputError naming the file
        and the problem (absent, too large, not JSON, wrong schema or
        shapes)."""
        p = Path(path)
        try:
            size = p.stat().st_size
        except FileNotFoundError:
            raise InputError(p, "no such device calibration file") from None
        if size > MAX_BYTES:
            raise InputError(p, f"{size} bytes; a {FORMAT} file is at most {MAX_BYTES}")
        try:
            text = p.read_text()
        except UnicodeDecodeError as e:
            raise InputError(p, f"not JSON ({str(e)[:80]})") from None
        return cls.from_text(text, p)

    @classmethod
    def from_text(cls, text: str, where="device calibration") -> DeviceCalibration:
        """Parse and check ``device/v1`` JSON text; InputError naming
        ``where`` (a file, or the DNG that carried it) and the problem."""
        if len(text.encode()) > MAX_BYTES:
            raise InputError(where, f"a {FORMAT} calibration is at most {MAX_BYTES} bytes")
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(where, f"not JSON ({str(e)[:80]})") from None
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise InputError(where, f"not a {FORMAT} file (format {got!r})")
        try:
            desc = np.asarray(d["descriptor"], dtype=np.float64)
            if desc.ndim != 3 or list(desc.shape[:2]) != list(d["grid"]) or desc.shape[2] != int(d["components"]):
                raise ValueError(f"descriptor shape {desc.shape} against grid {d['grid']} and "
                                 f"{d['components']} components")
            return cls(str(d["lens"]), str(d["design"]), str(d["basis"]), desc, tuple(d.get("effects", ())),
                       dict(d.get("fit", {})), dict(d.get("source", {})))
        except KeyError as e:
            raise InputError(where, f"{FORMAT} file without {e}") from None
        except (TypeError, ValueError) as e:
            raise InputError(where, str(e)) from None
