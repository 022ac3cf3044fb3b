"""What a proxy camera is fitted to: slanted-edge SFR observations over the
field.

An :class:`Observations` table holds one row per measured edge (or per
region aggregate): where it lies on the sensor, the direction of its normal,
the colour channel, its SFRA and SFR curve, their uncertainty, and the noise
and contrast measured on it — everything the forward model needs to predict
the same measurement and everything the loop closure needs to decompose the
residual (by field position, orientation, channel and frequency).

Conventions
-----------
* Sensor pixel coordinates ``(x_px, y_px)``: origin at the top-left pixel's
  centre, +x right, +y down (as :mod:`calibration.optics.psf.map`).
* ``normal_deg``: direction of the edge's normal in sensor coordinates,
  degrees counter-clockwise from +x *with y down* — i.e. the normal vector
  is ``(cos a, sin a)`` in (x, y) pixel coordinates; a near-vertical edge
  has a normal near 0° (or 180°), a near-horizontal one near 90°. The SFR
  along a normal and along its opposite are the same; values are kept in
  [0°, 180°).
* ``sfra``: area under the SFR from 0 to 0.5 cycles/pixel, cycles/pixel
  (a perfect system: 0.5; :mod:`calibration.sfr.esfr`).
* ``freq``: one common frequency grid (cycles/pixel) for all ``sfr`` rows.
* ``noise``: standard deviation of the flat parts of the edge, in the same
  0..1 linear units as ``step`` (the bright − dark difference); the forward
  model uses them to simulate the measurement's own noise (paper eq. 14:
  noise raises SFRA, so a noise-free simulation is biased).
* ``region``: (row, col) of the ROI centre in the field grid (default the
  paper's 15 × 20).
* ``odd``, ``odd_std`` (optional, (N, K)): the LSF's asymmetry, the odd part
  of the edge's transfer that the SFR drops, as band means
  (:mod:`calibration.sfr.asymmetry`), and its standard deviation from the
  measured noise.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.optics.lens import Sensor

GRID = (15, 20)
FREQ = np.linspace(0.0, 1.0, 129)   # cycles/pixel, to twice Nyquist


@dataclass(frozen=True, eq=False)
class Observations:
    """SFR observations over the field (see the module docstring).

    All per-observation arrays have length N; ``sfr`` is (N, F) on ``freq``.
    """

    x_px: np.ndarray
    y_px: np.ndarray
    normal_deg: np.ndarray
    channel: np.ndarray          # "R", "G", "B" or "L" (luminance)
    orientation: np.ndarray      # "sagittal", "tangential" or "axial"
    sfra: np.ndarray
    sfra_std: np.ndarray
    noise: np.ndarray
    step: np.ndarray
    freq: np.ndarray
    sfr: np.ndarray
    sensor: Sensor
    roi: np.ndarray | None = None            # (N, 4) x, y, w, h
    grid: tuple[int, int] = GRID
    source: str = ""
    meta: dict = field(default_factory=dict)
    odd: np.ndarray | None = None             # (N, K) LSF asymmetry bands
    odd_std: np.ndarray | None = None         # (N, K)

    def __post_init__(self):
        n = len(np.asarray(self.x_px))
        for name in ("y_px", "normal_deg", "channel", "orientation", "sfra", "sfra_std", "noise", "step"):
            if len(np.asarray(getattr(self, name))) != n:
                raise ValueError(f"observations: {name} has {len(getattr(self, name))} entries, expected {n}")
        if np.asarray(self.sfr).shape != (n, len(self.freq)):
            raise ValueError(f"observations: sfr must be ({n}, {len(self.freq)}), got {np.shape(self.sfr)}")
        if (self.odd is None) != (self.odd_std is None):
            raise ValueError("observations: odd and odd_std come together")
        if self.odd is not None and (np.shape(self.odd)[0] != n or np.shape(self.odd) != np.shape(self.odd_std)):
            raise ValueError(f"observations: odd and odd_std must be ({n}, K), got {np.shape(self.odd)} "
                             f"and {np.shape(self.odd_std)}")

    def with_fields(self, **changes) -> "Observations":
        """A copy with some fields replaced (``dataclasses.replace``)."""
        import dataclasses

        return dataclasses.replace(self, **changes)

    def __len__(self) -> int:
        return len(self.x_px)

    # -- derived -----------------------------------------------------------------
    @property
    def center_px(self) -> tuple[float, float]:
        """Optical centre assumed on the sensor (the array's centre)."""
        return ((self.sensor.width_px - 1) / 2.0, (self.sensor.height_px - 1) / 2.0)

    @property
    def radius(self) -> np.ndarray:
        """Normalised field radius of each observation (1 at the corner)."""
        cx, cy = self.center_px
        half = 0.5 * math.hypot(self.sensor.width_px, self.sensor.height_px)
        return np.hypot(np.asarray(self.x_px) - cx, np.asarray(self.y_px) - cy) / half

    @property
    def region(self) -> np.ndarray:
        """(N, 2) int (row, col) in the field grid."""
        rows, cols = self.grid
        r = np.clip((np.asarray(self.y_px) + 0.5) / self.sensor.height_px * rows, 0, rows - 1).astype(int)
        c = np.clip((np.asarray(self.x_px) + 0.5) / self.sensor.width_px * cols, 0, cols - 1).astype(int)
        return np.stack([r, c], axis=1)

    def subset(self, mask) -> "Observations":
        """The observations where ``mask`` (bool or index array) holds."""
        m = np.asarray(mask)
        rows = ("x_px", "y_px", "normal_deg", "channel", "orientation", "sfra", "sfra_std", "noise", "step", "sfr",
                "roi", "odd", "odd_std")     # the per-observation fields; the rest is shared
        return self.with_fields(meta=dict(self.meta), **{k: None if getattr(self, k) is None
                                                         else np.asarray(getattr(self, k))[m] for k in rows})

    def region_map(self, values=None, orientation: str | None = None, channel: str | None = None) -> np.ndarray:
        """(rows, cols) mean of ``values`` (default SFRA) per field region;
        NaN where a region has no matching observation."""
        v = np.asarray(self.sfra if values is None else values, dtype=np.float64)
        keep = np.ones(len(self), bool)
        if orientation is not None:
            keep &= np.asarray(self.orientation) == orientation
        if channel is not None:
            keep &= np.asarray(self.channel) == channel
        rows, cols = self.grid
        total, count = np.zeros((rows, cols)), np.zeros((rows, cols))
        reg = self.region
        for (r, c), x, k in zip(reg, v, keep):
            if k and np.isfinite(x):
                total[r, c] += x
                count[r, c] += 1
        with np.errstate(invalid="ignore"):
            return np.where(count > 0, total / np.maximum(count, 1), np.nan)

    # -- building ------------------------------------------------------------------
    @classmethod
    def from_sfr_results(cls, items, sensor: Sensor, *, channel: str = "G", grid=GRID, source: str = "",
                         default_std: float = 2e-3) -> "Observations":
        """Observations from ``(x_px, y_px, normal_deg, orientation, SfrResult)`` tuples
        (an SfrResult's SFR is resampled onto :data:`FREQ`; its bootstrap
        ``sfra_std`` is used where present, else ``default_std``; its LSF
        gives the asymmetry ``odd`` and, with its noise, ``odd_std``)."""
        from calibration.sfr.asymmetry import esf_bin_noise, odd_bands, odd_bands_std

        rows, odd, odd_sd = [], [], []
        for x, y, a, orient, r in items:
            sfr = np.interp(FREQ, r.freq, r.sfr, right=np.nan)
            sd = getattr(r, "sfra_std", None)
            std = float(sd) if sd is not None and np.isfinite(sd) and sd > 0 else default_std
            lo_hi = _step(r)
            rows.append((x, y, a % 180.0, channel, orient, r.sfra, std, r.noise, lo_hi, sfr))
            odd.append(odd_bands(r.lsf, r.esf_step_px))
            noise = r.noise if np.isfinite(r.noise) and r.noise > 0 else 0.01 * lo_hi
            over = int(r.settings.get("oversampling", 4)) if getattr(r, "settings", None) else 4
            odd_sd.append(odd_bands_std(r.lsf, r.esf_step_px, esf_bin_noise(noise, r.rows_used, over)))
        if not rows:
            raise ValueError("no SFR observations to fit to")
        cols = list(zip(*rows))
        return cls(np.array(cols[0], float), np.array(cols[1], float), np.array(cols[2], float),
                   np.array(cols[3]), np.array(cols[4]), np.array(cols[5], float), np.array(cols[6], float),
                   np.array(cols[7], float), np.array(cols[8], float), FREQ.copy(), np.array(cols[9], float),
                   sensor, grid=grid, source=source, odd=np.array(odd), odd_std=np.array(odd_sd))

    @classmethod
    def from_chart(cls, chart, sensor: Sensor, *, channel: str = "G", grid=GRID, source: str = "") -> "Observations":
        """Observations from a :class:`calibration.sfr.chart.ChartResult`
        measured on a capture of ``sensor``."""
        items = []
        for roi, r in chart.edges:
            x, y = roi.centre
            # SfrResult.angle_deg is the slope of the fitted edge line: x grows
            # with the row for a positive vertical edge angle, y with the column
            # for a horizontal one; the normal is perpendicular to that line
            normal = -r.angle_deg if r.orientation == "vertical" else 90.0 + r.angle_deg
            items.append((x - 0.5, y - 0.5, normal, roi.orientation, r))
        obs = cls.from_sfr_results(items, sensor, channel=channel, grid=grid, source=source)
        return obs.with_fields(roi=np.array([[roi.x, roi.y, roi.w, roi.h] for roi, _ in chart.edges]))

    # -- files ------------------------------------------------------------------------
    def to_dict(self) -> dict:
        def lst(a):
            a = np.asarray(a)
            return [None if (isinstance(v, float) and not math.isfinite(v)) else v for v in a.tolist()]

        return {"schema": "sfr-observations/v1", "source": self.source, "grid": list(self.grid),
                "sensor": {"pixel_pitch_um": self.sensor.pixel_pitch_um, "width_px": self.sensor.width_px,
                           "height_px": self.sensor.height_px},
                "freq": lst(self.freq),
                "observations": [
                    {"x_px": float(self.x_px[i]), "y_px": float(self.y_px[i]),
                     "normal_deg": float(self.normal_deg[i]), "channel": str(self.channel[i]),
                     "orientation": str(self.orientation[i]), "sfra": float(self.sfra[i]),
                     "sfra_std": float(self.sfra_std[i]), "noise": float(self.noise[i]),
                     "step": float(self.step[i]), "sfr": lst(self.sfr[i]),
                     **({"roi": [int(v) for v in self.roi[i]]} if self.roi is not None else {}),
                     **({"odd": lst(self.odd[i]), "odd_std": lst(self.odd_std[i])} if self.odd is not None else {})}
                    for i in range(len(self))],
                "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict, source: str = "") -> "Observations":
        if d.get("schema") != "sfr-observations/v1":
            raise ValueError(f"{source or 'observations'}: not an sfr-observations/v1 document")
        s = d["sensor"]
        obs = d["observations"]
        if not obs:
            raise ValueError(f"{source or 'observations'}: no observations")
        f = np.array(d["freq"], float)

        def col(k, dtype=float):
            return np.array([o[k] for o in obs], dtype=dtype)

        def rows_of(k):
            return np.array([[np.nan if v is None else v for v in o[k]] for o in obs], float)

        sfr = rows_of("sfr")
        roi = np.array([o["roi"] for o in obs], int) if all("roi" in o for o in obs) else None
        has_odd = all("odd" in o and "odd_std" in o for o in obs)

        return cls(col("x_px"), col("y_px"), col("normal_deg"), col("channel", object).astype(str),
                   col("orientation", object).astype(str), col("sfra"), col("sfra_std"), col("noise"),
                   col("step"), f, sfr, Sensor(**s), roi=roi, grid=tuple(d.get("grid", GRID)),
                   source=source or d.get("source", ""), meta=d.get("meta", {}),
                   odd=rows_of("odd") if has_odd else None, odd_std=rows_of("odd_std") if has_odd else None)

    def save(self, path) -> Path:
        from isp.io.files import write_bytes_atomic

        return write_bytes_atomic(path, json.dumps(self.to_dict()).encode())

    @classmethod
    def load(cls, path) -> "Observations":
        return cls.from_dict(json.loads(Path(path).read_text()), source=str(path))


def _step(r) -> float:
    """Bright − dark of an SfrResult's ESF plateaus (0..1 linear units)."""
    esf = np.asarray(r.esf, dtype=np.float64)
    m = max(4, esf.size // 10)
    return float(abs(esf[-m:].mean() - esf[:m].mean()))
