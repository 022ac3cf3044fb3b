"""Reading any lens file (calibration/optics/io/read.py): an unknown file
type, an unrecognised JSON lens and a missing file are one-line errors
naming the file.

Kind: property (each test marked).
"""

from __future__ import annotations


import pytest

from calibration.optics.io.read import read_lens

from tests.helpers import one_line_lens_error as one_line_error
from tests.helpers import write_lens_file as write


@pytest.mark.property
def test_unsupported_files(tmp_path):
    """property: unknown extension and unrecognised JSON name the file."""
    assert "unsupported lens file type '.txt'" in one_line_error(read_lens, write(tmp_path, "a.txt", "x"))
    assert "unrecognised JSON lens file" in one_line_error(read_lens, write(tmp_path, "a.json", "[1, 2]"))
    assert "cannot read" in one_line_error(read_lens, tmp_path / "missing.zmx")
