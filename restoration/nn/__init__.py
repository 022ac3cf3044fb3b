"""The restoration network: DOConv, the UNet, MAC counting, checkpoints (torch).

May import: torch, ``modules`` (stage math) and ``isp``.
"""
