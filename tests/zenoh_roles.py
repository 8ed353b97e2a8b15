"""The other processes of tests/test_zenoh_security.py, one Zenoh session each:

    python tests/zenoh_roles.py ROLE ENDPOINT CONFIG_JSON5|- [ACL on|off]

- ``service``: the service's ``ZenohPublisher`` on CONFIG listening on ENDPOINT; publishes
  what stdin says (one JSON line each: ``{"track": N, "lat": ...}`` or
  ``{"status": "..."}``) and prints ``{"done": K}`` after the K-th line;
- ``subscriber``: subscribes to ``tracker/**`` through ENDPOINT and prints every sample as
  a JSON line; on a line ``query`` from stdin, asks ``tracker/system_tracks/**`` and
  prints the replies then ``{"replies": n}``;
- ``forger``: a session that tries to publish a forged picture through ENDPOINT (a track
  moved 50 km, the track ended and deleted, a forged status and CAT062) and to answer
  queries with it, for a second, then prints ``{"linked": bool}`` (whether any link
  came up).

Each prints ``{"ready": true}`` once its session is open, and ends when stdin closes.
CONFIG ``-`` is no file at all (an unauthenticated peer); ``ACL off`` disables the
file's access control (a subscriber's certificate in an attacker's hands, with a
configuration of the attacker's own).
"""

from __future__ import annotations

import json
import sys
import threading
import time

import zenoh
from pydantic import BaseModel

from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_session import zenoh_config

FORGED_S = 1.0


class Message(BaseModel):
    number: int
    lat: float
    status: str
    origin: str


def say(doc: object) -> None:
    print(json.dumps(doc), flush=True)


def show(sample: zenoh.Sample) -> None:
    deleted = sample.kind == zenoh.SampleKind.DELETE
    payload = None if deleted else sample.payload.to_bytes().decode()
    say({"key": str(sample.key_expr), "deleted": deleted, "payload": payload})


def service(endpoint: str, config_file: str) -> None:
    with ZenohPublisher(listen=[endpoint], config_file=config_file) as publisher:
        say({"ready": True})
        for count, line in enumerate(sys.stdin, 1):
            doc = json.loads(line)
            if "track" in doc:
                message = Message(
                    number=doc["track"], lat=doc["lat"], status="confirmed", origin="service"
                )
                publisher.put_system_track(doc["track"], message)
            else:
                publisher.put_status(
                    Message(number=0, lat=0.0, status=doc["status"], origin="service")
                )
            say({"done": count})


def session_config(role: str, endpoint: str, config_file: str, acl: bool) -> zenoh.Config:
    # A forger is a peer that keeps trying: its session opens whether or not a link does.
    mode = "peer" if role == "forger" else None
    file = None if config_file == "-" else config_file
    config = zenoh_config(mode, connect=[endpoint], config_file=file)
    if role == "forger":
        config.insert_json5("connect/exit_on_failure", "false")
    if not acl:
        config.insert_json5("access_control/enabled", "false")
    return config


def subscriber(session: zenoh.Session) -> None:
    subscriber = session.declare_subscriber("tracker/**", show)
    say({"ready": True})
    for line in sys.stdin:
        if line.strip() == "query":
            replies = [r.ok for r in session.get("tracker/system_tracks/**", timeout=2.0)]
            for sample in replies:
                if sample is not None:
                    show(sample)
            say({"replies": sum(sample is not None for sample in replies)})
    subscriber.undeclare()  # type: ignore[no-untyped-call]


def forger(session: zenoh.Session) -> None:
    moved = Message(number=7, lat=48.5 + 0.45, status="confirmed", origin="forged")  # 50 km N
    ended = moved.model_copy(update={"status": "ended"})
    status = Message(number=0, lat=0.0, status="ok", origin="forged")
    lock = threading.Lock()

    def answer(query: zenoh.Query) -> None:
        with lock:
            query.reply("tracker/system_tracks/7", moved.model_dump_json())

    queryable = session.declare_queryable("tracker/system_tracks/**", answer)
    say({"ready": True})
    deadline = time.monotonic() + FORGED_S
    while time.monotonic() < deadline:
        session.put("tracker/system_tracks/7", moved.model_dump_json())
        session.put("tracker/system_tracks/7", ended.model_dump_json())
        session.delete("tracker/system_tracks/7")
        session.put("tracker/status", status.model_dump_json())
        # What the bytes of a forged CAT062 block are does not matter here: JSON, so
        # that the test reads every sample alike.
        session.put("tracker/cat062", status.model_dump_json())
        time.sleep(0.02)
    info = session.info
    say({"linked": bool(info.peers_zid() or info.routers_zid())})
    sys.stdin.read()
    queryable.undeclare()  # type: ignore[no-untyped-call]


def main() -> None:
    role, endpoint, config_file = sys.argv[1:4]
    acl = sys.argv[4:5] != ["off"]
    if role == "service":
        service(endpoint, config_file)
        return
    with zenoh.open(session_config(role, endpoint, config_file, acl)) as session:
        subscriber(session) if role == "subscriber" else forger(session)


if __name__ == "__main__":
    main()
