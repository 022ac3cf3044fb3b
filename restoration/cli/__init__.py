"""``isp synth``, ``isp train``, ``isp eval``: argument parsing only; commands call library functions.

The three commands' records (:class:`isp.cli.commands.Command`) are here,
and ``pyproject.toml`` names them in the ``isp.commands`` entry-point group:
importing this package imports nothing else, so ``isp --help`` lists them
without loading torch or the optics.

May import: everything in ``restoration`` and ``isp`` (here at the top
level: :mod:`isp.cli.commands` only).
"""

from isp.cli.commands import Command

SYNTH = Command("synth", "training pairs from latent images through a proxy camera",
                module="restoration.cli.synth")
TRAIN = Command("train", "train the optical-correction network on synthesised pairs",
                module="restoration.cli.train")
EVAL = Command("eval", "PSNR/SSIM per field ring of a correction model on unseen proxy cameras",
               module="restoration.cli.eval")
