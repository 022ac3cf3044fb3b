"""From lens prescription to proxy camera: lens files, ray tracer, PSF, edge
imaging, ISO 12233 SFR, the proxy-camera fitter and loop closure.

May import :mod:`isp` (for DNG writing); never :mod:`modules`'s internals or
torch. (Contents arrive with the optics and SFR issues.)
"""
