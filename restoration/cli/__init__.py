"""``isp synth``, ``isp train``, ``isp eval``: argument parsing only.

May import: everything in ``restoration``.
"""
