"""Proxy cameras: observations, the SFR forward model, damped least squares, the proxy fit, the pixel competitor, synthetic devices.

May import: ``calibration.optics``, ``calibration.sfr.esfr``, ``calibration.simulate``, ``calibration.report``, ``isp``.
"""
