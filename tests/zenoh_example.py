"""The shipped Zenoh security example (config/zenoh/) copied into a test's directory,
beside certificates made by the shipped make-certs.sh (none is committed)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import REPO

EXAMPLE = REPO / "config" / "zenoh"


def make_certs(directory: Path, ca: Path | None = None, subscriber: str | None = None) -> None:
    """``directory/certs``: a CA (or ``ca``'s), the service's and a subscriber's
    certificates (the subscriber's common name ``subscriber`` when given)."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is absent: no certificates to test with")
    environment = dict(os.environ)
    if ca is not None:
        environment["CA"] = str(ca)
    if subscriber is not None:
        environment["SUBSCRIBER"] = subscriber
    subprocess.run(
        ["sh", str(EXAMPLE / "make-certs.sh"), str(directory / "certs")],
        check=True,
        capture_output=True,
        env=environment,
    )


def example_copy(directory: Path) -> Path:
    """``directory`` holding service.json5 and subscriber.json5 as shipped, and certs/."""
    make_certs(directory)
    for name in ("service.json5", "subscriber.json5"):
        shutil.copy(EXAMPLE / name, directory / name)
    return directory
