"""The shipped Zenoh security example (config/zenoh/) copied into a test's directory,
beside certificates made by the shipped make-certs.sh (none is committed)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import REPO

EXAMPLE = REPO / "config" / "zenoh"


def make_certs(directory: Path) -> None:
    """``directory/certs``: a CA, the service's and a subscriber's certificates."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is absent: no certificates to test with")
    subprocess.run(
        ["sh", str(EXAMPLE / "make-certs.sh"), str(directory / "certs")],
        check=True,
        capture_output=True,
    )


def example_copy(directory: Path) -> Path:
    """``directory`` holding service.json5 and subscriber.json5 as shipped, and certs/."""
    make_certs(directory)
    for name in ("service.json5", "subscriber.json5"):
        shutil.copy(EXAMPLE / name, directory / name)
    return directory
