"""Helpers shared by the built-in stages, and public to the packages above
them: tiled execution with overlap (:mod:`.tiling`), per-CFA-phase
arithmetic on mosaics (:mod:`.mosaic`), array-API helpers that let one
function run on numpy and torch (:mod:`.xp`), the DNG colour model
(:mod:`.dng_colour`), the maths of Adobe's render: camera-profile tables
(:mod:`.dng_profile`) and tone curves (:mod:`.dng_tone`), and what the
encoding stages share: orientation, EXIF, ICC profiles (:mod:`.encoding`).

They are a package of their own, not private to ``modules``, because
``restoration`` needs the same code: its model runner tiles a frame exactly
as the correction stage does, and data synthesis inverts the same DNG colour
model; a second copy would drift.

May import: numpy, OpenCV, colour-science, and ``isp``; nothing of the
stages themselves.
"""
