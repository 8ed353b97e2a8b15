"""The shipped mTLS + access-control example (config/zenoh/) with real Zenoh sessions in
separate processes on 127.0.0.1: a forged picture from an unauthenticated peer, from a
peer with a certificate of another CA, or from a subscriber with a real certificate,
never reaches an authenticated subscriber; the service's own publications do."""

from __future__ import annotations

import json
import queue
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import REPO
from tests.zenoh_example import example_copy, make_certs

ROLES = Path(__file__).with_name("zenoh_roles.py")
TIMEOUT_S = 10.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@dataclass(frozen=True)
class Pki:
    service: Path
    """The shipped service.json5, beside certs/ made by the shipped make-certs.sh."""
    subscriber: Path
    """The shipped subscriber.json5, beside its certificate of the same CA."""
    rogue: Path
    """subscriber.json5 beside certificates of another CA (one named tracker-service)."""
    no_certificate: Path
    """TLS with the right CA but no certificate of its own."""
    unlisted: Path
    """subscriber.json5 beside a certificate of the right CA, with a common name the
    service's access control does not list."""


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    base = example_copy(tmp_path_factory.mktemp("pki"))
    rogue = base / "rogue"
    make_certs(rogue)
    # The rogue's subscriber identity, as the service's name, under the rogue CA.
    for ext in ("crt", "key"):
        shutil.copy(rogue / "certs" / f"service.{ext}", rogue / "certs" / f"subscriber.{ext}")
    shutil.copy(base / "subscriber.json5", rogue / "subscriber.json5")
    unlisted = base / "unlisted"
    make_certs(unlisted, ca=base / "certs", subscriber="ops-unlisted")
    shutil.copy(base / "subscriber.json5", unlisted / "subscriber.json5")
    no_certificate = base / "no-certificate.json5"
    no_certificate.write_text(
        json.dumps(
            {
                "mode": "peer",
                "transport": {
                    "link": {"tls": {"root_ca_certificate": str(base / "certs" / "ca.crt")}}
                },
            }
        )
    )
    return Pki(
        base / "service.json5",
        base / "subscriber.json5",
        rogue / "subscriber.json5",
        no_certificate,
        unlisted / "subscriber.json5",
    )


class Party:
    """One role of tests/zenoh_roles.py in its own process, read line by line (by a
    thread: a pipe's lines arrive in bursts that a select on it would not see)."""

    def __init__(self, *args: str) -> None:
        self.name = f"{args[0]} {args[2]}"
        self.process = subprocess.Popen(
            [sys.executable, str(ROLES), *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read_lines, daemon=True).start()

    def ready(self) -> Party:
        assert self.read() == {"ready": True}
        return self

    def _read_lines(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line)
        self._lines.put("")

    def poll(self, timeout: float) -> dict[str, Any] | None:
        """The next line, or None when none comes within ``timeout`` seconds."""
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            return None
        assert line, f"{self.name} ended (exit {self.process.wait()})"
        doc: dict[str, Any] = json.loads(line)
        return doc

    def read(self) -> dict[str, Any]:
        doc = self.poll(TIMEOUT_S)
        assert doc is not None, f"{self.name}: nothing within {TIMEOUT_S} s"
        return doc

    def send(self, line: str) -> None:
        stdin = self.process.stdin
        assert stdin is not None
        stdin.write(line + "\n")
        stdin.flush()

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        try:
            self.process.wait(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


@pytest.fixture
def parties() -> Iterator[list[Party]]:
    started: list[Party] = []
    yield started
    for party in reversed(started):
        party.close()


def samples_until(subscriber: Party, status: str) -> list[dict[str, Any]]:
    """The samples up to the service's status message ``status``."""
    got = []
    while True:
        doc = subscriber.read()
        got.append(doc)
        if doc.get("key") == "tracker/status" and json.loads(doc["payload"])["status"] == status:
            return got


def linked_service(
    parties: list[Party], service_config: Path, pki: Pki
) -> tuple[str, Party, Party]:
    """The service and an authenticated subscriber that has received from it."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    service = Party("service", endpoint, str(service_config))
    parties.append(service.ready())
    subscriber = Party("subscriber", endpoint, str(pki.subscriber))
    parties.append(subscriber.ready())
    # The subscription reaches the service some time after it is declared: probe.
    deadline = time.monotonic() + TIMEOUT_S
    while (first := subscriber.poll(0.05)) is None:
        assert time.monotonic() < deadline, "no probe reached the authenticated subscriber"
        service.send(json.dumps({"status": "probe"}))
    assert json.loads(first["payload"])["origin"] == "service"
    return endpoint, service, subscriber


def test_forged_picture_does_not_reach_an_authenticated_subscriber(
    pki: Pki, parties: list[Party]
) -> None:
    endpoint, service, subscriber = linked_service(parties, pki.service, pki)
    unlisted = Party("subscriber", endpoint, str(pki.unlisted))
    parties.append(unlisted)
    service.send(json.dumps({"track": 7, "lat": 48.5}))
    plaintext = endpoint.replace("tls/", "tcp/")
    forgers = {
        "unauthenticated, plaintext": Party("forger", plaintext, "-"),
        "unauthenticated, TLS": Party("forger", endpoint, str(pki.no_certificate)),
        "certificate of another CA": Party("forger", endpoint, str(pki.rogue)),
        "subscriber's certificate": Party("forger", endpoint, str(pki.subscriber), "off"),
    }
    parties.extend(forgers.values())
    for party in (unlisted, *forgers.values()):
        party.ready()
    linked = {name: forger.read()["linked"] for name, forger in forgers.items()}
    # Only the subscriber's own certificate opens a link; what it sends is dropped there.
    assert linked == {
        "unauthenticated, plaintext": False,
        "unauthenticated, TLS": False,
        "certificate of another CA": False,
        "subscriber's certificate": True,
    }
    service.send(json.dumps({"track": 7, "lat": 48.6}))
    service.send(json.dumps({"status": "end of test"}))
    got = samples_until(subscriber, "end of test")
    assert not [doc for doc in got if doc["deleted"]]
    messages = [(doc["key"], json.loads(doc["payload"])) for doc in got]
    assert {message["origin"] for _, message in messages} == {"service"}
    tracks = [(m["number"], m["lat"]) for key, m in messages if "system_tracks" in key]
    assert tracks == [(7, 48.5), (7, 48.6)]
    # The picture a late joiner asks for is the service's alone: the forgers' queryables
    # are not reached.
    subscriber.send("query")
    replies = []
    while "replies" not in (doc := subscriber.read()):
        replies.append(json.loads(doc["payload"]))
    assert replies == [{"number": 7, "lat": 48.6, "status": "confirmed", "origin": "service"}]
    # A certificate of the right CA whose name the access control does not list: a
    # link, and nothing on it.
    unlisted.send("query")
    assert unlisted.read() == {"replies": 0}
    assert unlisted.poll(0.2) is None


def test_without_access_control_a_subscriber_could_forge(pki: Pki, parties: list[Party]) -> None:
    """The control of the test above: with the service's access control off (and nothing
    else changed), a peer holding a subscriber's certificate moves the track on every
    other subscriber's picture. What stops it above is the access control."""
    text = pki.service.read_text()
    open_door = text.replace(
        "access_control: {\n    enabled: true", "access_control: {\n    enabled: false"
    )
    assert open_door != text
    no_acl = pki.service.with_name("service-without-acl.json5")
    no_acl.write_text(open_door)
    endpoint, service, subscriber = linked_service(parties, no_acl, pki)
    forger = Party("forger", endpoint, str(pki.subscriber), "off")
    parties.append(forger.ready())
    assert forger.read() == {"linked": True}
    service.send(json.dumps({"status": "end of test"}))
    got = samples_until(subscriber, "end of test")
    forged = [
        doc for doc in got if doc["deleted"] or json.loads(doc["payload"])["origin"] == "forged"
    ]
    assert {doc["key"] for doc in forged} == {
        "tracker/system_tracks/7",
        "tracker/status",
        "tracker/cat062",
    }


def test_replay_publishes_over_mutual_tls_to_an_authenticated_subscriber(
    pki: Pki, parties: list[Party]
) -> None:
    """The whole service (``tracker-service replay`` of the bundled recording) on the
    shipped example: its system tracks reach a subscriber holding a subscriber's
    certificate."""
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    service = subprocess.Popen(
        [
            *(sys.executable, "-m", "tracker_service.cli", "replay"),
            *("recordings/three_sites.mcap", "--speed", "20"),
            *("--zenoh-config", str(pki.service), "--zenoh-listen", endpoint),
        ],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert service.stderr is not None
        hint = service.stderr.readline()
        assert "--zenoh-config SUBSCRIBER.json5 --connect " + endpoint in hint
        # A client's session needs the service's listener up.
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "the replay never listened"
                time.sleep(0.05)
        subscriber = Party("subscriber", endpoint, str(pki.subscriber))
        parties.append(subscriber.ready())
        while "system_tracks" not in (sample := subscriber.read())["key"]:
            pass
        track = json.loads(sample["payload"])
        assert sample["key"] == f"tracker/system_tracks/{track['number']}"
        assert {"lat", "lon", "status"} <= track.keys()
    finally:
        service.terminate()
        service.wait(timeout=TIMEOUT_S)
