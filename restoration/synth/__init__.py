"""Training pairs from proxy cameras (paper, section 4.1): colour inversion, optics, sensor, shards.

May import: ``calibration``, ``modules``, ``isp``; numpy only (no torch).
"""
