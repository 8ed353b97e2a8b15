"""What the fault-injection tests (tests/test_faults_*.py) and benchmarks/soak.py share:
hostile datagrams, a daemon configuration on loopback ports, a daemon in another
process with its status read from the health file."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from asterix.codec import encode_block
from asterix.plots import extract_plots

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "config" / "example.toml"
CONFIGURED = {(25, 11), (25, 12), (25, 13), (25, 50)}
"""The SAC/SICs of config/example.toml (and of the three_sites scenario)."""
NO_I010 = bytes.fromhex("300009302032 00071c")
"""A CAT048 record without I010 (a plot at 50 NM with no source): seen to stop status."""
MALFORMED = b"\x30\x00\x02garbage"
STARTUP_S = 60.0


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def plot_record(sac: int, sic: int, time_of_day: float, rho_nm: float = 40.0) -> dict[str, Any]:
    """The items of one well-formed SSR plot of source SAC/SIC."""
    return {
        "010": {"SAC": sac, "SIC": sic},
        "140": time_of_day % 86400.0,
        "020": {"TYP": 2, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0},
        "040": {"RHO": rho_nm, "THETA": 123.0},
    }


def plot_block(sac: int, sic: int, time_of_day: float, rho_nm: float = 40.0) -> bytes:
    """A CAT048 data block of one well-formed SSR plot of source SAC/SIC."""
    return encode_block(48, [plot_record(sac, sic, time_of_day, rho_nm)])


def _no_configured_plot(payload: bytes) -> bool:
    """True when no plot in ``payload`` names a configured radar: random bytes that did
    would be a forged plot, which no check can tell from a real one."""
    plots = extract_plots(payload).plots
    return not any(
        (int(a), int(b)) in CONFIGURED for a, b in zip(plots["sac"], plots["sic"], strict=True)
    )


def hostile_datagrams(rng: np.random.Generator, time_of_day: float) -> Iterator[tuple[str, bytes]]:
    """One of each kind of hostile datagram, endlessly, as (kind, payload): what an
    attacker on the feed's LAN, or a broken radar, sends. None of them carries a plot of
    a configured radar (see ``_no_configured_plot``)."""
    while True:
        yield "no_i010", NO_I010
        yield "malformed", MALFORMED
        yield "random", rng.bytes(65507)
        size = int(rng.integers(4, 65507))
        while True:
            body = rng.bytes(size - 3)
            random48 = bytes([48]) + size.to_bytes(2, "big") + body
            if _no_configured_plot(random48):
                break
        yield "random_cat048", random48
        yield "unknown_category", bytes([99, 0, 8]) + rng.bytes(5)
        # FSPEC announces I010, I140, I020, I040, then the block ends.
        yield "truncated_record", bytes([48, 0, 6, 0xF0, 25, 99])
        sac, sic = int(rng.integers(0, 256)), int(rng.integers(0, 256))
        if (sac, sic) not in CONFIGURED:
            yield "unknown_source", plot_block(sac, sic, time_of_day)


def write_config(
    tmp: Path,
    *,
    holding_window_s: float = 0.2,
    log: bool = True,
    system: dict[str, Any] | None = None,
    periods_s: float | None = None,
    second_lan: bool = False,
) -> tuple[Path, dict[str, int]]:
    """config/example.toml with unicast inputs on free loopback ports (the port of each
    feed by its key; with ``second_lan``, 25/11 has a LAN B too, its port under
    "25/11 B"), ``system`` settings added to [system], and, with ``periods_s``, every
    antenna period replaced (short silences in short tests)."""
    tmp.mkdir(parents=True, exist_ok=True)
    keys = ["25/11", "25/12", "25/13", "25/50"]
    ports = {key: free_port() for key in keys}
    if second_lan:
        ports["25/11 B"] = free_port()

    def table(key: str) -> str:
        extra = ""
        if key + " B" in ports:
            extra = f', second_lan = {{ address = "127.0.0.1", port = {ports[key + " B"]} }}'
        return f'input = {{ address = "127.0.0.1", port = {ports[key]}{extra} }}'

    text = EXAMPLE.read_text(encoding="utf-8")
    inputs = iter(table(key) for key in keys)
    text = re.sub(r"(?m)^input = .*$", lambda _: next(inputs), text)
    text = re.sub(r"(?m)^holding_window_s = .*$", f"holding_window_s = {holding_window_s}", text)
    for name, value in (system or {}).items():
        line = f"{name} = {value}"
        text, found = re.subn(rf"(?m)^{name} = .*$", line, text)
        if not found:
            text = text.replace("[system]\n", f"[system]\n{line}\n", 1)
    if periods_s is not None:
        text = re.sub(r"(?m)^antenna_period_s = .*$", f"antenna_period_s = {periods_s}", text)
    directory = f'directory = "{tmp / "logs"}"' if log else ""
    text = re.sub(r"(?m)^directory = .*$", directory, text)
    config = tmp / "tracker.toml"
    config.write_text(text, encoding="utf-8")
    return config, ports


class DaemonProcess:
    """``tracker-service run`` in another process; its stderr kept; ``status()`` is the
    last status it wrote into its health file."""

    def __init__(
        self,
        config: Path,
        health: Path,
        *,
        wait: str | None = "running:",
        role: tuple[str, ...] = (),
    ) -> None:
        """``role``: ``run``'s role arguments (``--role radar --radars 25/11
        --stage-connect ...``); a radar process gets no health file (it has no status)."""
        self.health = health
        self.lines: list[str] = []
        command = [sys.executable, "-m", "tracker_service.cli", "run", "--config", str(config)]
        if "radar" not in role:
            command += ["--zenoh-listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
            command += ["--health-file", str(health)]
        self.process = subprocess.Popen(
            [*command, *role],
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        self._events: dict[str, threading.Event] = {}
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()
        if wait is not None:
            self.wait_for(wait)

    def _drain(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            with self._lock:
                self.lines.append(line.rstrip())
                for text, event in self._events.items():
                    if text in line:
                        event.set()

    def wait_for(self, text: str, timeout: float = STARTUP_S) -> None:
        with self._lock:
            event = self._events.setdefault(text, threading.Event())
            if any(text in line for line in self.lines):
                event.set()
        assert event.wait(timeout), f"no {text!r} within {timeout} s:\n" + self.log()

    def log(self) -> str:
        with self._lock:
            return "\n".join(self.lines)

    def status(self) -> dict[str, Any]:
        doc: dict[str, Any] = json.loads(self.health.read_text(encoding="utf-8"))
        return doc

    def wait_status(self, condition: Any, timeout: float = 30.0) -> dict[str, Any]:
        """The first status (polled) for which ``condition(status)`` holds."""
        deadline = time.monotonic() + timeout
        last: dict[str, Any] = {}
        while time.monotonic() < deadline:
            try:
                last = self.status()
                if condition(last):
                    return last
            except (OSError, ValueError):
                pass
            assert self.process.poll() is None, "the daemon ended:\n" + self.log()
            time.sleep(0.1)
        raise AssertionError(f"no such status within {timeout} s; last: {last}\n{self.log()}")

    def radar(self, key: str) -> dict[str, Any]:
        return next(r for r in self.status()["radars"] if r["radar"] == key)

    def children(self) -> list[int]:
        """Process ids of the daemon's children (the output process, multiprocessing's
        resource tracker)."""
        pid = self.process.pid
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text(encoding="utf-8")
        return [int(p) for p in text.split()]

    def output_process(self) -> int:
        for child in self.children():
            cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
            if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
                return child
        raise AssertionError("no output process among the daemon's children")

    def rss_mb(self) -> float:
        """Resident memory of the daemon's process (the core), MB."""
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
        raise AssertionError("no VmRSS")

    def stop(self, timeout: float = 30.0) -> int:
        self.process.send_signal(signal.SIGTERM)
        return self.process.wait(timeout=timeout)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self._reader.join(timeout=5.0)


def send(port: int, payloads: list[bytes], pause_every: int = 0, pause_s: float = 0.0) -> None:
    """Each payload to 127.0.0.1:port, optionally pausing every ``pause_every``."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
        for i, payload in enumerate(payloads):
            sock.sendto(payload, ("127.0.0.1", port))
            if pause_every and (i + 1) % pause_every == 0:
                time.sleep(pause_s)


def stop_process(pid: int, timeout: float = 10.0) -> None:
    """SIGSTOP ``pid`` and wait until every thread of it is stopped: the group stop
    reaches each thread when it next runs, and on a loaded machine a socket thread could
    still read for a while after the signal was sent."""
    os.kill(pid, signal.SIGSTOP)
    deadline = time.monotonic() + timeout
    tasks = Path(f"/proc/{pid}/task")
    while True:
        states = []
        for task in tasks.iterdir():
            with contextlib.suppress(OSError):
                stat = (task / "stat").read_text(encoding="utf-8")
                states.append(stat[stat.rindex(")") + 2])
        if states and all(state in "Tt" for state in states):
            return
        assert time.monotonic() < deadline, f"process {pid} not stopped: {states}"
        time.sleep(0.01)


def pids_alive(pids: list[int]) -> list[int]:
    alive = []
    for pid in pids:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        alive.append(pid)
    return alive
