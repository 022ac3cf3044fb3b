"""Simulated captures: the optical image, the sensor, charts and scenes, whole captures written as DNG.

May import: ``calibration.optics``, ``calibration.sfr.esfr``, ``isp``.
"""
