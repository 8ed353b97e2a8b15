"""Shared test helpers: where the shared sample data lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# A worktree beside the repository (../wt/NAME) names the data with TRACKER_SHARED_DATA.
SHARED_DATA = Path(
    os.environ.get("TRACKER_SHARED_DATA", REPO.parent / "shared" / "data" / "asterix")
)


def shared_file(relative: str) -> Path:
    """A file of ../shared/data/asterix, or a skip saying why it is missing."""
    path = SHARED_DATA / relative
    if not path.is_file():
        pytest.skip(f"{path} is absent: the shared sample data (GPL/LGPL) is not beside the repo")
    return path
