"""Figures and reports of the fit and the loop, written so that a reader
never sees half a file.

Every file goes through a temporary file in the same folder and a rename
(:func:`isp.io.files.write_bytes_atomic`): :func:`save_figure` for
matplotlib figures, :func:`write_json` for JSON documents, :func:`write_npz`
for numpy archives. A report folder
is built whole in a temporary folder beside its destination and published
at the end (:func:`staged_folder`, :func:`publish_folder`), so a run that
fails leaves nothing behind; :func:`check_output_folder` refuses a
destination that cannot be a folder before the work starts.

Imports ``isp`` (atomic writes, errors) and matplotlib (lazily); nothing
else of :mod:`calibration`, so :mod:`calibration.fit` and
:mod:`calibration.loop` can use it and the command line can too.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from isp.errors import InputError
from isp.io.files import write_bytes_atomic

__all__ = ["check_output_folder", "publish_folder", "save_figure", "staged_folder", "write_json", "write_npz"]


def save_figure(fig, path, *, dpi: int = 120) -> None:
    """Save a matplotlib figure atomically (PNG/PDF/SVG by suffix) and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        The file; its suffix picks the format (none: PNG).
    dpi : int
        Resolution of raster formats (an annotated chart of hundreds of
        edges wants more than a plot of curves).
    """
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


def write_json(path, doc, *, indent: int = 2) -> Path:
    """Write ``doc`` as JSON (``indent`` spaces), atomically; returns the path.

    >>> import tempfile, pathlib
    >>> p = write_json(pathlib.Path(tempfile.mkdtemp()) / "a.json", {"x": 1})
    >>> p.read_text()
    '{\\n  "x": 1\\n}'
    """
    return write_bytes_atomic(Path(path), json.dumps(doc, indent=indent).encode())


def write_npz(path, arrays: dict, compressed: bool = False) -> Path:
    """Write ``arrays`` (name → array) as an ``.npz`` (deflated with
    ``compressed``), atomically; returns the path."""
    import numpy as np

    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return write_bytes_atomic(Path(path), buf.getvalue())


def check_output_folder(out) -> None:
    """Refuse an output folder that exists as something else (a file).

    Raises
    ------
    InputError
        ``out`` exists and is not a folder.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")


def publish_folder(tmp, out) -> None:
    """Move a finished report from the folder ``tmp`` to ``out``: one rename
    when ``out`` does not exist; file by file, each atomic, when it does
    (files of ``out`` that the report does not write are kept)."""
    tmp, out = Path(tmp), Path(out)
    if not out.exists():
        os.replace(tmp, out)
        return
    for f in tmp.iterdir():
        os.replace(f, out / f.name)
    tmp.rmdir()


@contextmanager
def staged_folder(out) -> Iterator[Path]:
    """A temporary folder beside ``out`` to build a report in; published to
    ``out`` (:func:`publish_folder`) when the block ends without an error,
    removed in every case.

    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "report"
    >>> with staged_folder(out) as tmp:
    ...     _ = (tmp / "a.txt").write_text("done")
    >>> (out / "a.txt").read_text()
    'done'
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        yield tmp
        publish_folder(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
