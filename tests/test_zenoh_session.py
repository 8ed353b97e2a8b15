"""The Zenoh session's configuration: endpoints that add, scouting off unless asked for,
TLS never silently plaintext, and the command line's one-line errors."""

from __future__ import annotations

import json
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from tests.conftest import REPO
from tests.zenoh_example import example_copy
from tracker_service.cli import build_parser
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_session import (
    PlaintextEndpointError,
    ZenohConfigError,
    zenoh_config,
)
from tracker_service.service.command import _with_cli
from tracker_service.service.config import ConfigError, load_service_config


@pytest.fixture(scope="module")
def example(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return example_copy(tmp_path_factory.mktemp("example"))


def get(config: zenoh.Config, key: str) -> object:
    value: object = json.loads(config.get_json(key))
    return value


def write(path: Path, doc: dict[str, object]) -> Path:
    path.write_text(json.dumps(doc))
    return path


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def test_endpoints_add_to_the_files(tmp_path: Path) -> None:
    file = write(
        tmp_path / "z.json5",
        {
            "listen": {"endpoints": ["tcp/127.0.0.1:7001"]},
            "connect": {"endpoints": {"peer": ["tcp/127.0.0.1:7002"], "router": []}},
        },
    )
    config = zenoh_config(
        listen=["tcp/127.0.0.1:7003", "tcp/127.0.0.1:7001"],
        connect=["tcp/127.0.0.1:7004"],
        config_file=file,
    )
    assert get(config, "listen/endpoints") == ["tcp/127.0.0.1:7001", "tcp/127.0.0.1:7003"]
    # The file's endpoints for the session's mode (a list per mode in Zenoh's format).
    assert get(config, "connect/endpoints") == ["tcp/127.0.0.1:7002", "tcp/127.0.0.1:7004"]
    assert get(config, "mode") == "peer"


def test_a_session_listens_on_the_files_endpoint_and_the_added_one(tmp_path: Path) -> None:
    ports = free_port(), free_port()
    file = write(tmp_path / "z.json5", {"listen": {"endpoints": [f"tcp/127.0.0.1:{ports[0]}"]}})
    with ZenohPublisher(listen=[f"tcp/127.0.0.1:{ports[1]}"], config_file=file):
        for port in ports:
            socket.create_connection(("127.0.0.1", port), timeout=2.0).close()


def test_nothing_named_listens_nowhere_and_scouting_is_off() -> None:
    config = zenoh_config()
    # Zenoh's own default is a peer listening on tcp/[::]:0, every interface.
    assert get(config, "listen/endpoints") == []
    assert get(config, "scouting/multicast/enabled") is False
    assert get(config, "scouting/gossip/enabled") is False
    assert get(zenoh_config(scouting=True), "scouting/gossip/enabled") is True


def test_scouting_the_file_asks_for_is_kept(tmp_path: Path) -> None:
    file = write(tmp_path / "z.json5", {"scouting": {"multicast": {"enabled": True}}})
    config = zenoh_config(config_file=file)
    assert get(config, "scouting/multicast/enabled") is True
    assert get(config, "scouting/gossip/enabled") is False


def test_mode_is_the_files_unless_given(example: Path) -> None:
    file = example / "subscriber.json5"
    assert get(zenoh_config(config_file=file, connect=["tls/localhost:1"]), "mode") == "client"
    assert get(zenoh_config("peer", config_file=file), "mode") == "peer"


@pytest.mark.parametrize(
    "tls",
    [
        {"transport": {"link": {"tls": {"root_ca_certificate": "certs/ca.crt"}}}},
        {"transport": {"link": {"protocols": ["tls", "quic"]}}},
        {"connect": {"endpoints": ["tls/192.0.2.1:7447"]}},
    ],
    ids=["certificates", "protocols", "endpoints"],
)
def test_plaintext_added_to_tls_is_refused(example: Path, tls: dict[str, object]) -> None:
    file = write(example / "tls.json5", tls)
    with pytest.raises(PlaintextEndpointError) as raised:
        zenoh_config(listen=["tcp/0.0.0.0:7447"], config_file=file)
    assert str(raised.value) == (
        f"listen endpoint tcp/0.0.0.0:7447 is plaintext but {file} configures TLS: use "
        "listen endpoint tls/0.0.0.0:7447, or allow plaintext explicitly to add it anyway"
    )
    with pytest.raises(PlaintextEndpointError, match="connect endpoint udp/"):
        zenoh_config(connect=["tls/10.0.0.1:7447", "udp/10.0.0.1:7447"], config_file=file)
    allowed = zenoh_config(listen=["tcp/0.0.0.0:7447"], config_file=file, allow_plaintext=True)
    assert "tcp/0.0.0.0:7447" in str(get(allowed, "listen/endpoints"))
    # TLS on TLS, and plaintext without any TLS, are what was asked.
    zenoh_config(connect=["tls/192.0.2.2:7447", "quic/192.0.2.2:7447"], config_file=file)
    zenoh_config(listen=["tcp/0.0.0.0:7447"])


def test_relative_files_are_taken_from_the_files_directory(example: Path) -> None:
    config = zenoh_config(config_file=example / "service.json5")
    certs = example.absolute() / "certs"
    assert get(config, "transport/link/tls/root_ca_certificate") == str(certs / "ca.crt")
    assert get(config, "transport/link/tls/listen_private_key") == str(certs / "service.key")


def test_unusable_file_is_one_line(tmp_path: Path) -> None:
    file = tmp_path / "bad.json5"
    file.write_text('{ access_control: { rules: [{ id: "x", messages: ["publish"] }] } }')
    with pytest.raises(ZenohConfigError) as raised:
        zenoh_config(config_file=file)
    message = str(raised.value)
    assert message.startswith(f"{file}: not a usable Zenoh configuration: ")
    assert "unknown variant `publish`" in message and ".rs:" not in message
    assert "\n" not in message


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tracker_service.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )


def test_missing_or_unreadable_certificate_is_one_line(example: Path, tmp_path: Path) -> None:
    file = write(
        tmp_path / "z.json5", {"transport": {"link": {"tls": {"listen_certificate": "x.crt"}}}}
    )
    with pytest.raises(ZenohConfigError) as raised:
        zenoh_config(config_file=file)
    assert str(raised.value) == (
        f"{file}: transport/link/tls/listen_certificate {tmp_path / 'x.crt'}: no such file "
        "(certificates and keys: config/zenoh/make-certs.sh, docs/security.md)"
    )


def test_tls_listener_without_certificate_is_one_line() -> None:
    with pytest.raises(ZenohConfigError) as raised:
        zenoh_config(listen=["tls/0.0.0.0:7447"])
    assert str(raised.value).startswith(
        "listen endpoint tls/0.0.0.0:7447 is TLS but no certificate is configured: give a "
        "Zenoh configuration file with transport/link/tls/listen_certificate"
    )


def test_toml_and_cli_endpoints_add_and_a_tomls_plaintext_is_named(
    example: Path, tmp_path: Path
) -> None:
    text = (REPO / "config" / "example.toml").read_text()
    assert "listen = []" in text
    toml = tmp_path / "tracker.toml"
    toml.write_text(text.replace("listen = []", 'listen = ["tls/127.0.0.1:7001"]', 1))
    parser = build_parser()
    args = parser.parse_args(
        [
            *("run", "--config", str(toml), "--zenoh-listen", "tls/127.0.0.1:7002"),
            *("--zenoh-config", str(example / "service.json5"), "--zenoh-scouting"),
        ]
    )
    settings = _with_cli(load_service_config(toml), args).zenoh
    assert settings.listen == ["tls/127.0.0.1:7001", "tls/127.0.0.1:7002"]
    assert settings.scouting
    toml.write_text(text.replace("listen = []", 'listen = ["tcp/127.0.0.1:7001"]', 1))
    args = parser.parse_args(
        ["run", "--config", str(toml), "--zenoh-config", str(example / "service.json5")]
    )
    with pytest.raises(ConfigError) as raised:
        _with_cli(load_service_config(toml), args)
    assert str(raised.value).startswith(
        "[zenoh] listen tcp/127.0.0.1:7001 is plaintext but "
    ) and str(raised.value).endswith(
        "use [zenoh] listen tls/127.0.0.1:7001, or set [zenoh] allow_plaintext = true "
        "to add it anyway"
    )


def test_cli_refuses_plaintext_beside_tls_naming_the_option(example: Path) -> None:
    # The Dockerfile's old command on the TLS example: refused before anything starts.
    done = run_cli(
        "run",
        "--config",
        "config/example.toml",
        "--zenoh-config",
        str(example / "service.json5"),
        "--zenoh-listen",
        "tcp/0.0.0.0:7447",
    )
    assert done.returncode == 2
    assert done.stderr == (
        "tracker-service run: --zenoh-listen tcp/0.0.0.0:7447 is plaintext but "
        f"{example / 'service.json5'} configures TLS: use --zenoh-listen tls/0.0.0.0:7447, "
        "or give --zenoh-allow-plaintext to add it anyway\n"
    )


def test_subscribe_needs_somewhere_to_find_the_service(example: Path) -> None:
    done = run_cli("subscribe", "--json")
    assert done.returncode == 2
    assert "give --connect ENDPOINT" in done.stderr and done.stderr.count("\n") == 1
    done = run_cli(
        "subscribe", "--zenoh-config", str(example / "subscriber.json5"), "--connect", "tcp/h:1"
    )
    assert done.returncode == 2
    assert "--connect tcp/h:1 is plaintext" in done.stderr and "--allow-plaintext" in done.stderr


def dockerfile_command() -> list[str]:
    text = (REPO / "Dockerfile").read_text().replace("\\\n", " ")
    match = re.search(r"^CMD (\[.*\])$", text, re.MULTILINE)
    assert match, "the Dockerfile has no CMD in exec form"
    command: list[str] = json.loads(match.group(1))
    return command


def test_docker_command_keeps_tls(example: Path, tmp_path: Path) -> None:
    """The image's command, on a volume holding tracker.toml and the example with its
    certificates, listens on TLS only, with the example's access control."""
    volume = tmp_path / "config"
    shutil.copytree(example, volume / "zenoh")
    shutil.copy(REPO / "config" / "example.toml", volume / "tracker.toml")
    command = [arg.replace("/config/", f"{volume}/") for arg in dockerfile_command()]
    args = build_parser().parse_args(command)
    zenoh_settings = _with_cli(load_service_config(args.config), args).zenoh
    assert zenoh_settings.config_file == volume / "zenoh" / "service.json5"
    assert zenoh_settings.listen == ["tls/0.0.0.0:7447"] and zenoh_settings.connect == []
    assert not zenoh_settings.allow_plaintext and not zenoh_settings.scouting
    config = zenoh_config(config_file=zenoh_settings.config_file)
    assert get(config, "access_control/enabled") is True
    assert get(config, "transport/link/tls/enable_mtls") is True
