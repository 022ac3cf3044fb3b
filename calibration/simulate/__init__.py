"""Simulated captures: the optical image, the sensor, charts and scenes, the device simulated (:mod:`.device`:
nominal, drawn within tolerance, or a given perturbation), whole captures written as DNG.

May import: ``calibration.optics``, ``calibration.sfr.esfr``, ``isp``.
"""
