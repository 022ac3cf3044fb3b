"""Closing the loop: base models, the registry of physical effects, the closure that adds them and refits.

May import: ``calibration.fit`` and everything it may import.
"""
