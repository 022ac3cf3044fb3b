"""The kind markers (kind: property): the root ``conftest.py`` stops a run
whose tests do not carry exactly one of ``published`` / ``golden`` /
``property``, and gives doctests the kind ``property`` before ``-m``
selects. Each case runs pytest on a small folder with a copy of that
``conftest.py``."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.property

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("published", "golden", "property")


def _pytest(tmp_path, files: dict, *args):
    shutil.copy(ROOT / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n" + "".join(f"    {k}: kind\n" for k in KINDS))
    for name, text in files.items():
        (tmp_path / name).write_text(textwrap.dedent(text))
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args, str(tmp_path)],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    return out.returncode, out.stdout + out.stderr


def test_a_test_without_a_kind_stops_the_run(tmp_path):
    code, out = _pytest(tmp_path, {"test_x.py": """
        import pytest

        @pytest.mark.published
        def test_cited():
            pass

        def test_bare():
            pass
    """})
    assert code != 0
    assert "test_x.py::test_bare: no kind" in out and "test_cited" not in out.split("need exactly one kind")[1]


def test_a_test_with_two_kinds_stops_the_run(tmp_path):
    code, out = _pytest(tmp_path, {"test_x.py": """
        import pytest

        pytestmark = pytest.mark.property

        @pytest.mark.golden
        def test_both():
            pass
    """})
    assert code != 0 and "test_x.py::test_both: kinds golden, property" in out


def test_doctests_are_property_and_selected_by_it(tmp_path):
    files = {"mod.py": '''
        def twice(x):
            """Twice ``x``.

            >>> twice(2)
            4
            """
            return 2 * x
    ''', "test_x.py": """
        import pytest

        pytestmark = pytest.mark.published

        def test_cited():
            pass
    """}
    code, out = _pytest(tmp_path, files, "--doctest-modules", "-m", "property")
    assert code == 0 and re.search(r"1 passed, 1 deselected", out), out
    code, out = _pytest(tmp_path, files, "--doctest-modules", "-m", "published")
    assert code == 0 and re.search(r"1 passed, 1 deselected", out), out


def test_the_kinds_are_registered():
    table = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    registered = {m.split(":")[0] for m in table["markers"]}
    assert set(KINDS) <= registered
    assert "--strict-markers" in table["addopts"]
