"""Where the synthesis inputs are by default: the shared data folder and the phone DNGs.

``isp synth``, ``isp eval``, the training config's ``data:`` paths
(:func:`restoration.train.config.resolve_path`) and the benchmarks read the
same folder: ``../shared/data`` beside the repository, or ``$ISP_DATA``.
"""

from __future__ import annotations

import os
from pathlib import Path

#: the shared data folder beside the repository (``$ISP_DATA`` overrides)
DATA = Path(os.environ.get("ISP_DATA") or Path(__file__).resolve().parents[3] / "shared" / "data")

#: phone DNGs whose metadata is used by default (the first is the sensor), relative to :data:`DATA`
DEFAULT_CAMERAS = ("raw/SYNTHETIC_phone_S6meta_512x384.dng", "raw/skia_sample_1mp.dng")
