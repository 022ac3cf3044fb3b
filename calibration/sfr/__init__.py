"""ISO 12233 slanted-edge SFR: the e-SFR core, edge measurement, charts, LSF asymmetry, exact synthetic edges.

May import: numpy, scipy, OpenCV and ``isp`` errors; never ``calibration.optics`` (the SFR knows nothing of lenses).
"""
