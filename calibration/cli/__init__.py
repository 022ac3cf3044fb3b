"""``isp calib``: argument parsing for the calibration toolkit; calls library functions only.

May import: everything in ``calibration`` and ``isp``.
"""
