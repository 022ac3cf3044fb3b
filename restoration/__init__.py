"""DOConv restoration (paper, section 4): training pairs synthesised from
proxy cameras (:mod:`.synth`), the network (:mod:`.nn`), training
(:mod:`.train`), evaluation on unseen proxies (:mod:`.evaluate`) and the
``isp synth`` / ``train`` / ``eval`` commands (:mod:`.cli`).

May import: ``isp``, ``modules`` (the stages after the correction slot run
in the loss), ``calibration`` (proxy cameras, PSF maps), numpy and torch;
never ``export``.
"""
