"""Shared test helpers: where the shared sample data lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# A worktree beside the repo (../wt/NAME) finds the data through TRACKER_SHARED_DIR.
SHARED = Path(os.environ.get("TRACKER_SHARED_DIR", REPO.parent / "shared"))
SHARED_DATA = SHARED / "data" / "asterix"


def shared_file(relative: str) -> Path:
    """A file of ../shared/data/asterix, or a skip saying why it is missing."""
    path = SHARED_DATA / relative
    if not path.is_file():
        pytest.skip(f"{path} is absent: the shared sample data (GPL/LGPL) is not beside the repo")
    return path


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Files holding a ``slow`` test first, the rest in their order: with ``make test``
    (pytest-xdist, ``--dist loadfile``) the long ones start at once on the two workers
    instead of ending the run on one of them. The same order in every worker (xdist
    requires it): a stable sort on a key of the item's own file."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)
