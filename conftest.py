"""Root pytest configuration (covers the doctests in the packages too).

Every collected test carries exactly one kind marker (registered in
``pyproject.toml``):

* ``published`` — against an outside published reference (a standard, a
  paper, a maker's data sheet: the tables in ``tests/data/reference``) or a
  peer's output (LibRaw/rawpy, colour-hdri, sfrmat, MTF Mapper, optiland,
  scipy); ``pytest -m published`` runs these;
* ``golden`` — regression against stored values, with the script that
  regenerates them;
* ``property`` — round trips, invariants, closed forms, parity between forms
  of the same function. Doctests are examples that must keep running: they
  are marked ``property`` here.

A test module sets ``pytestmark = pytest.mark.KIND``, or marks each test
where it mixes kinds. Collection stops with the list of tests that carry no
kind or more than one.
"""

import importlib.util

import numpy as np
import pytest
from _pytest.doctest import DoctestItem

KINDS = ("published", "golden", "property")

# the doctests of restoration/ and export/ import torch (the ``train`` extra)
collect_ignore = [] if importlib.util.find_spec("torch") else ["restoration", "export"]


def kind_errors(items) -> list[str]:
    """``nodeid: what is wrong`` for each item without exactly one kind marker."""
    errors = []
    for item in items:
        kinds = sorted({m.name for m in item.iter_markers() if m.name in KINDS})
        if len(kinds) != 1:
            errors.append(f"{item.nodeid}: {'no kind' if not kinds else 'kinds ' + ', '.join(kinds)}")
    return errors


@pytest.hookimpl(tryfirst=True)   # before ``-m`` deselects: doctests get their kind first
def pytest_collection_modifyitems(config, items):
    for item in items:
        if isinstance(item, DoctestItem):
            item.add_marker(pytest.mark.property)
    errors = kind_errors(items)
    if errors:
        raise pytest.UsageError(
            f"{len(errors)} test(s) need exactly one kind marker ({' / '.join(KINDS)}; "
            "set pytestmark = pytest.mark.KIND in the module or mark the test):\n  " + "\n  ".join(errors))


@pytest.fixture(autouse=True)
def _numpy_print_style():
    """colour-science sets numpy's legacy 1.13 print style on import; doctests
    that print arrays need the current one whatever was imported first."""
    np.set_printoptions(legacy=False)
    yield
