"""Issue 11 finding 4: a unicast feed cannot be stolen, and a port in use is a clear error.

Real sockets on 127.0.0.1, a second process binding the same port as a thief would
(with SO_REUSEADDR), a second daemon started on the same configuration."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.fault_tools import DaemonProcess, plot_block, write_config
from tracker_service.inputs.udp import EndpointError, UdpEndpoint, UdpInput

# Another process, of any user, trying to share the port the way SO_REUSEADDR allows.
THIEF = r"""
import socket, sys
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
try:
    sock.bind((sys.argv[1], int(sys.argv[2])))
except OSError as exc:
    print("refused", exc.errno, flush=True)
    sys.exit(0)
print("bound", flush=True)
sock.settimeout(3.0)
got = 0
try:
    while True:
        sock.recv(65535)
        got += 1
except TimeoutError:
    pass
print("stole", got, flush=True)
"""


@pytest.mark.parametrize("address", ["127.0.0.1", "0.0.0.0"])
def test_another_process_cannot_bind_a_unicast_input(address: str) -> None:
    with UdpInput("r1", UdpEndpoint(address, 0)) as feed:
        port = feed.endpoints[0][1]
        thief = subprocess.run(
            [sys.executable, "-c", THIEF, "127.0.0.1", str(port)],
            capture_output=True,
            text=True,
            timeout=30,
            input=None,
        )
        assert thief.stdout.split()[0] == "refused", thief.stdout
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
            for n in range(20):
                out.sendto(plot_block(25, 11, float(n)), ("127.0.0.1", port))
        deadline = time.monotonic() + 5.0
        while feed.counters.received < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert feed.counters.delivered == 20


def test_a_port_in_use_is_an_error_naming_it() -> None:
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0)) as feed:
        port = feed.endpoints[0][1]
        with pytest.raises(EndpointError) as caught:
            UdpInput("r2", UdpEndpoint("127.0.0.1", port))
    assert f"127.0.0.1:{port} is already bound by another process" in caught.value.reason
    assert caught.value.endpoint.port == port


def test_a_second_daemon_fails_with_one_clear_line(tmp_path: Path) -> None:
    config, ports = write_config(tmp_path, log=False)
    first = DaemonProcess(config, tmp_path / "health")
    try:
        second = subprocess.run(
            [sys.executable, "-m", "tracker_service.cli", "run", "--config", str(config)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert second.returncode == 2, second.stderr
        lines = [line for line in second.stderr.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("tracker-service run:")]
        assert len(errors) == 1, second.stderr
        port = ports["25/11"]
        assert "radars[0].input.port" in errors[0]
        assert f"127.0.0.1:{port} is already bound by another process" in errors[0]
        assert "Traceback" not in second.stderr
        # The first one still has its feeds.
        assert first.process.poll() is None
    finally:
        assert first.stop() == 0, first.log()
        first.close()


def test_multicast_inputs_still_share_a_group() -> None:
    """SO_REUSEADDR stays on multicast sockets: two receivers of one group on one host
    (the two LANs' groups on one port, a second application) each get every datagram."""
    group = "239.255.71.14"
    try:
        first = UdpInput("a", UdpEndpoint(group, 0, interface="127.0.0.1"))
    except OSError as exc:
        pytest.skip(f"cannot join {group} on loopback: {exc}")
    port = first.endpoints[0][1]
    with first, UdpInput("b", UdpEndpoint(group, port, interface="127.0.0.1")) as second:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
            out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
            out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            out.sendto(plot_block(25, 11, 1.0), (group, port))
        got = first.get(2.0), second.get(2.0)
    if got == (None, None):
        pytest.skip("the kernel does not loop multicast back on lo")
    assert all(g is not None for g in got)
