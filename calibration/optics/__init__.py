"""Lens model and geometric optics: lenses, materials, paraxial optics, perturbations, relative illumination, spot diagrams and the real-ray tracer.

May import: numpy, scipy, and ``isp`` (errors); nothing of ``calibration.sfr.esfr``, ``simulate``, ``fit`` or ``loop``.
"""
