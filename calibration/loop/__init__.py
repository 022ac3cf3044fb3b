"""Closing the loop: base models (and the one a measurement asks for, :func:`.base.make_base`), the registry of
physical effects, the closure that adds them and refits, and its report.

May import: ``calibration.fit`` and everything it may import.
"""
