"""Point spread functions from the exit pupil: pupil sampling and the reference sphere, the Huygens, FFT and Debye methods, polychromatic PSFs, Strehl ratio, PSF maps.

May import: ``calibration.optics`` and numpy/scipy/colour-science.
"""
