"""Training the correction network: configuration, data loading, the training loop.

May import: ``restoration.nn``, ``restoration.synth.pairs``, ``modules``, ``isp``.
"""
