"""Frames, domains and colour filter arrays: the data every stage passes on.

A :class:`Frame` is an immutable record of one image on its way through the
pipeline: its pixels, the *domain* they are in, the camera's metadata and the
stages already applied. Stages never modify a frame; they return a new one.

Data convention (written once, here)
------------------------------------
========================  =================  ==================================
domain                    ``data``           values
========================  =================  ==================================
``raw``                   (H, W) or (H,W,3)  float32 sensor DN, black not removed
``raw_linear``            (H, W) or (H,W,3)  float32, black = 0, white = 1
``camera_rgb``            (H, W, 3)          float32 linear camera RGB, balanced
``linear_rgb``            (H, W, 3)          float32 linear working RGB (sRGB
                                             primaries, D65)
``display_rgb``           (H, W, 3)          float32 encoded (e.g. sRGB OETF),
                                             0..1
``encoded``               (N,) uint8         a file's bytes (JPEG)
========================  =================  ==================================

Nothing is clipped before the encoding stage: lens-shading gains and white
balance legitimately push linear values above 1.

A frame in ``raw``/``raw_linear`` with three channels comes from a *linear*
DNG (PhotometricInterpretation LinearRaw): demosaicing was done in camera, so
the demosaic stage passes it through, but black level, linearisation, opcodes
and white balance still apply. The domain says how far processing got; the
array's shape says whether it is a mosaic.
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:   # for the annotation only: isp.meta is heavier than a frame needs
    from isp.meta import CameraMeta


class Domain(enum.Enum):
    """Processing state of a frame, in pipeline order (see the module table)."""

    RAW = "raw"
    RAW_LINEAR = "raw_linear"
    CAMERA_RGB = "camera_rgb"
    LINEAR_RGB = "linear_rgb"
    DISPLAY_RGB = "display_rgb"
    ENCODED = "encoded"

    @property
    def order(self) -> int:
        """Position in the processing chain, 0 for ``raw``."""
        return list(Domain).index(self)

    @classmethod
    def parse(cls, value: "str | Domain") -> "Domain":
        """``Domain`` from its name; the error lists the valid names."""
        if isinstance(value, Domain):
            return value
        try:
            return cls(str(value).lower())
        except ValueError:
            names = ", ".join(d.value for d in cls)
            raise ValueError(f"unknown domain {value!r}; valid: {names}") from None

    def __str__(self) -> str:
        return self.value


class CFA(enum.Enum):
    """A 2×2 Bayer colour filter array, named by its top-left 2×2 block read
    row by row (``GRBG``: G at (0, 0), R at (0, 1), B at (1, 0), G at (1, 1)).

    Channel indices are 0 = R, 1 = G, 2 = B. Only Bayer layouts exist here:
    X-Trans and four-colour sensors are refused at the reader.
    """

    RGGB = "RGGB"
    BGGR = "BGGR"
    GRBG = "GRBG"
    GBRG = "GBRG"

    @property
    def pattern(self) -> np.ndarray:
        """(2, 2) int array of channel indices (0 R, 1 G, 2 B)."""
        lookup = {"R": 0, "G": 1, "B": 2}
        return np.array([lookup[c] for c in self.value]).reshape(2, 2)

    def positions(self, channel: int) -> list[tuple[int, int]]:
        """(row, col) offsets inside the 2×2 block that hold ``channel``."""
        return [(r, c) for r in range(2) for c in range(2) if self.pattern[r, c] == channel]

    def shifted(self, dy: int, dx: int) -> "CFA":
        """The pattern seen from a crop whose origin is ``(dy, dx)`` pixels
        into this one (odd offsets change the phase)."""
        p = np.roll(self.pattern, shift=(-dy % 2, -dx % 2), axis=(0, 1))
        return CFA.from_pattern(p)

    @classmethod
    def from_pattern(cls, pattern) -> "CFA":
        """CFA from a (2, 2) array of channel indices 0 R, 1 G, 2 B."""
        p = np.asarray(pattern).reshape(2, 2)
        name = "".join("RGB"[int(v)] if 0 <= int(v) <= 2 else "?" for v in p.ravel())
        try:
            return cls(name)
        except ValueError:
            raise ValueError(f"not a Bayer pattern: {name}") from None

    @classmethod
    def parse(cls, value: "str | CFA") -> "CFA":
        if isinstance(value, CFA):
            return value
        try:
            return cls(str(value).upper())
        except ValueError:
            names = ", ".join(c.value for c in cls)
            raise ValueError(f"unknown CFA {value!r}; valid: {names}") from None


@dataclass(frozen=True)
class Step:
    """One entry of a frame's history: which stage ran and what it decided
    (e.g. ``"as-shot neutral (0.55, 1, 0.48)"`` or ``"skipped: no GainMap"``)."""

    stage: str
    note: str = ""

    def __str__(self) -> str:
        return f"{self.stage}: {self.note}" if self.note else self.stage


@dataclass(frozen=True, eq=False)
class Frame:
    """An image on its way through the pipeline (immutable).

    Attributes
    ----------
    data : ndarray
        float32 pixels, (H, W) mosaic or (H, W, 3); (N,) uint8 when encoded.
    domain : Domain
        How far processing got; see the module table.
    meta : isp.meta.CameraMeta
        What the file said about the camera, and where this data sits on the
        sensor (``meta.origin``). Named, not imported: :mod:`isp.meta` builds
        on this module's :class:`CFA`, so this module imports nothing of it.
    history : tuple of Step
        Stages applied so far, oldest first.
    neutral : tuple of 3 float or None
        The camera-space neutral (R, G, B) the data was white-balanced for,
        set by the white-balance stage; the colour stage needs it to undo the
        balance where the DNG colour model asks for unbalanced camera RGB.
    """

    data: Any
    domain: Domain
    meta: "CameraMeta"
    history: tuple = ()
    neutral: tuple | None = None

    def __post_init__(self):
        if not isinstance(self.domain, Domain):
            object.__setattr__(self, "domain", Domain.parse(self.domain))

    @property
    def mosaic(self) -> bool:
        """True while the data is a one-channel CFA mosaic."""
        return self.domain is not Domain.ENCODED and self.data.ndim == 2

    @property
    def shape(self) -> tuple:
        return tuple(self.data.shape)

    @property
    def full_size(self) -> tuple[int, int]:
        """(H, W) of the full frame this data is a crop of: the sensor's
        active area, or, for a frame made in code without one, the data
        itself (plus its origin). Opcode maps and field positions are
        relative to it."""
        ah, aw = self.meta.active_size
        oy, ox = self.meta.origin
        h, w = self.data.shape[:2]
        return (max(ah, oy + h), max(aw, ox + w))

    def evolve(self, data=None, *, domain: Domain | None = None, note: str = "",
               stage: str | None = None, **changes) -> "Frame":
        """A new frame with ``data`` (and any other field) replaced, and one
        history step appended when ``stage`` is given."""
        history = self.history
        if stage is not None:
            history = history + (Step(stage, note),)
        return dataclasses.replace(
            self,
            data=self.data if data is None else data,
            domain=self.domain if domain is None else domain,
            history=history,
            **changes,
        )
