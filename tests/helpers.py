"""Where the shared data lives, for tests (``../shared/data`` beside the repo)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def data_file(*parts: str) -> Path:
    """Path of a shared data file; skips the test with the reason if absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not available: {p} (tests that use ../shared/data skip without it)")
    return p
