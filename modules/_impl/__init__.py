"""Helpers shared by the built-in stages: tiling, per-CFA arithmetic, array-API helpers, the DNG colour model.

May import: numpy, OpenCV, colour-science, and ``isp``.
"""
