"""Proxy cameras: observations (:mod:`.observations`) and the measurements
they are read from (:mod:`.measurements`: a chart capture, an SFR JSON, an
observations file), the SFR forward model, damped least squares, the proxy
fit, the pixel competitor, synthetic devices.

May import: ``calibration.optics``, ``calibration.sfr``, ``calibration.simulate``, ``calibration.report``, ``isp``.
"""
