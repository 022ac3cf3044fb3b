"""ISO 12233 slanted-edge SFR: the e-SFR core, edge measurement, charts, LSF asymmetry, exact synthetic edges,
and the images measured (:mod:`.images`: an image file's codes, or a raw capture's linear mosaic).

May import: numpy, scipy, OpenCV and ``isp`` (errors; raw files read through its pipeline); never
``calibration.optics`` (the SFR knows nothing of lenses).
"""
