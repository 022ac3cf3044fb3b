"""Evaluation on unseen proxy cameras: PSNR/SSIM per field ring, model runners, the classical baseline.

May import: ``restoration.nn``, ``restoration.synth.pairs``, ``calibration``, ``modules``, ``isp``.
"""
