"""The packaged correction models and their lens profiles (package data).

Each model file (``*.onnx``, provenance in ``README.md`` here) comes with a
profile file (``*.toml``, schema ``profile/v1``, :mod:`isp.profiles`) naming
the lens identity it corrects; the ``correction`` stage runs a model only on
captures of its lens. The profiles reach :mod:`isp.profiles` through the
``isp.profiles`` entry points in ``pyproject.toml``, which name the paths
below.

May import: the standard library only (it holds paths).
"""

from pathlib import Path

#: the default phone lens's profile (US-12210142-B2 embodiment 9)
E9_DEFAULT = Path(__file__).with_name("e9_default.toml")
