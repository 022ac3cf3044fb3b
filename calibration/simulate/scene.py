"""The demo scene's constants: the demo camera's colour and the ColorChecker.

Shared by ``isp demo`` (:mod:`calibration.demo`) and the simulator
(:mod:`calibration.simulate.chart`, :mod:`calibration.simulate.capture`), which
import them from here, downward, instead of from the demo.

References: IEC 61966-2-1:1999 (sRGB), clause 5.2 (eq. 8 and its inverse) and
5.3 (decoding); X-Rite / BabelColor, "ColorChecker sRGB values" (D65).
"""

from __future__ import annotations

import numpy as np

#: ColorChecker 24 in 8-bit sRGB (X-Rite / BabelColor "sRGB values", D65),
#: row by row from dark skin to black
COLORCHECKER_SRGB8 = np.array([
    [115, 82, 68], [194, 150, 130], [98, 122, 157], [87, 108, 67], [133, 128, 177], [103, 189, 170],
    [214, 126, 44], [80, 91, 166], [193, 90, 99], [94, 60, 108], [157, 188, 64], [224, 163, 46],
    [56, 61, 150], [70, 148, 73], [175, 54, 60], [231, 199, 31], [187, 86, 149], [8, 133, 161],
    [243, 243, 242], [200, 200, 200], [160, 160, 160], [122, 122, 121], [85, 85, 85], [52, 52, 52],
], dtype=np.float64)

#: XYZ → linear sRGB (IEC 61966-2-1:1999, eq. 8 inverse), D65
XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])

#: the demo sensor's spectral mixing: camera RGB = C · linear sRGB
CAMERA_MIX = np.array([[0.78, 0.30, -0.08],
                       [0.12, 0.92, -0.04],
                       [0.04, 0.26, 0.70]])


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding of values in [0, 1]."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
