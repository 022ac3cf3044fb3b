"""Lens files: the JSON format ``lens/v1`` and importers of Zemax, optiland, rayoptics and DeepLens files.

May import: ``calibration.optics``.
"""
