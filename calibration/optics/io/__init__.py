"""Lens files: the project's JSON format ``lens/v1`` (:mod:`.lens_json`),
importers of Zemax ``.zmx`` (:mod:`.zmx`), optiland (:mod:`.optiland`),
rayoptics (:mod:`.rayoptics`) and DeepLens (:mod:`.deeplens`) files, what
they share (:mod:`.common`: messages naming the file, defaults for what a
file leaves out), and :func:`read_lens` (:mod:`.read`), which picks the
reader by file type.

May import: ``calibration.optics`` and ``isp`` (atomic file writes). Inside
the package the imports run one way: common → lens_json and the importers
→ read.
"""

from calibration.optics.io.lens_json import lens_from_dict, lens_to_dict, load_lens, save_lens
from calibration.optics.io.read import FORMATS, read_lens

__all__ = ["FORMATS", "lens_from_dict", "lens_to_dict", "load_lens", "read_lens", "save_lens"]
