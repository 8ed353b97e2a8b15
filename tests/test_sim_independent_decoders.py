"""The simulator's output decodes: with our codec, and with two decoders written by others.

A minute of ``config/scenarios/three_sites.toml`` (three radars, one of them dual-LAN, and
an ADS-B ground station) is simulated to MCAP and to a raw capture. Every datagram must
decode with our codec without a single error event and encode back to the same bytes.
Then two independent decoders read the same bytes and must agree with ours:

- pyobelix (pure Python, CAT048 and CAT034; installed beside our codec by the ``test``
  extra), on every radar datagram, field by field;
- libasterix 0.36.3 (CAT048 1.32, CAT034 1.29, CAT021 2.7), on the raw capture. It
  installs the import name ``asterix`` as our codec does, so it lives in a virtual
  environment of its own (made under pytest's temporary directory, or kept in
  ``$TRACKER_TEST_VENVS/libasterix`` when that variable names a directory) and runs a
  small script in a subprocess, which prints every record as a JSON line.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import subprocess
import sys
import textwrap
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from asterix import Block, decode_blocks, encode_block
from asterix.containers import Datagram, read_datagrams, read_file
from tracker_service.simulator.recording import RecordedDatagram, read_recording
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "config" / "scenarios" / "three_sites.toml"
DURATION_S = 60.0
RADARS = {"25/11", "25/12", "25/13"}
ADSB = {"25/50"}
LIBASTERIX = "libasterix==0.36.3"
PIP_TIMEOUT_S = 600


@dataclass(frozen=True)
class Simulated:
    mcap: Path
    raw: Path
    pcap: Path
    datagrams: list[RecordedDatagram]
    """The MCAP recording's datagrams, in reception-time order."""


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Simulated:
    folder = tmp_path_factory.mktemp("three_sites")
    scenario = load_scenario(SCENARIO)
    paths = [folder / f"three_sites.{suffix}" for suffix in ("mcap", "raw", "pcap")]
    for path in paths:
        simulate(scenario, path, duration_s=DURATION_S)
    return Simulated(*paths, list(read_recording(paths[0]).datagrams()))


def _blocks(payload: bytes, offset: int = 0) -> list[Block]:
    events = list(decode_blocks(payload, offset))
    errors = [e for e in events if not isinstance(e, Block)]
    assert not errors, errors
    blocks = [e for e in events if isinstance(e, Block)]
    assert all(b.supported and b.records for b in blocks), blocks
    return blocks


def test_every_datagram_decodes_without_error_and_encodes_back(simulated: Simulated) -> None:
    assert {d.source for d in simulated.datagrams} == RADARS | ADSB
    categories: Counter[tuple[str, int]] = Counter()
    for d in simulated.datagrams:
        assert len(d.payload) <= 1472
        end = 0
        for block in _blocks(d.payload):
            assert block.offset == end
            end = block.offset + int.from_bytes(d.payload[block.offset + 1 : block.offset + 3])
            raw = d.payload[block.offset : end]
            assert encode_block(block.cat, block.records) == raw
            categories[d.source, block.cat] += len(block.records)
            sac, sic = (int(x) for x in d.source.split("/"))
            assert all(r["010"] == {"SAC": sac, "SIC": sic} for r in block.records)
        assert end == len(d.payload)
    assert {cat for _source, cat in categories} == {21, 34, 48}
    for source in RADARS:
        assert categories[source, 48] > 100 and categories[source, 34] > 50
    assert categories["25/50", 21] > 500
    assert not {source for source, cat in categories if cat == 21} & RADARS
    # The captures hold the same datagrams (both LANs) as the MCAP recording.
    recorded = Counter(d.payload for d in simulated.datagrams)
    assert Counter(d.payload for d in read_file(simulated.pcap) if isinstance(d, Datagram)) == (
        recorded
    )
    raw = simulated.raw.read_bytes()
    assert len(raw) == sum(len(d.payload) for d in simulated.datagrams)
    assert Counter(raw[d.offset : d.offset + len(d.payload)] for d in _raw_blocks(raw)) == Counter(
        block for d in simulated.datagrams for block in _split(d.payload)
    )


def test_captures_are_in_reception_time_order(simulated: Simulated) -> None:
    times = [d.time for d in read_file(simulated.pcap) if isinstance(d, Datagram)]
    assert len(times) == len(simulated.datagrams)
    backwards = [(a, b) for a, b in itertools.pairwise(times) if b < a]
    assert not backwards
    assert simulated.raw.read_bytes() == b"".join(d.payload for d in simulated.datagrams)


def _split(payload: bytes) -> list[bytes]:
    """The data blocks of a datagram."""
    out, pos = [], 0
    while pos < len(payload):
        end = pos + int.from_bytes(payload[pos + 1 : pos + 3])
        out.append(payload[pos:end])
        pos = end
    return out


def _raw_blocks(raw: bytes) -> list[Datagram]:
    units = list(read_datagrams(raw, "raw"))
    assert all(isinstance(u, Datagram) for u in units)
    return [u for u in units if isinstance(u, Datagram)]


# ---------------------------------------------------------------------------
# pyobelix
# ---------------------------------------------------------------------------


def _obelix_048(r: dict[str, Any]) -> dict[str, Any]:
    """What pyobelix 0.1 gives for one of our CAT048 records (its own names and types)."""
    out: dict[str, Any] = {"cat": 48}
    for item, value in r.items():
        if item == "010":
            out |= {"sac": value["SAC"], "sic": value["SIC"]}
        elif item == "140":
            out["time_of_day"] = value
        elif item == "020":
            out |= {
                "typ": value["TYP"],
                "sim": bool(value["SIM"]),
                "rdp": bool(value["RDP"]),
                "spi": bool(value["SPI"]),
                "rab": bool(value["RAB"]),
            }
            if "TST" in value:
                out |= {
                    "tst": bool(value["TST"]),
                    "err": bool(value["ERR"]),
                    "xpp": bool(value["XPP"]),
                    "me": bool(value["ME"]),
                    "mi": bool(value["MI"]),
                    "foefri": value["FOEFRI"],
                }
        elif item == "040":
            out |= {"rho": value["RHO"], "theta": value["THETA"]}
        elif item == "070":
            out |= {
                "squawk": value["MODE3A"],
                "squawk_valid": not value["V"],
                "squawk_garbled": bool(value["G"]),
                "squawk_local": bool(value["L"]),
            }
        elif item == "090":
            out |= {"flight_level": value["FL"], "fl_valid": not value["V"]}
            out["fl_garbled"] = bool(value["G"])
        elif item == "220":
            out["icao"] = value
        elif item == "240":
            out["callsign"] = value
        elif item == "250":
            out["mode_s_mb"] = [
                {"mb": m["MBDATA"], "bds": m["BDS1"] * 16 + m["BDS2"]} for m in value
            ]
        elif item == "230":
            out |= {
                "com": value["COM"],
                "stat": value["STAT"],
                "si": value["SI"],
                "mssc": bool(value["MSSC"]),
                "arc": bool(value["ARC"]),
                "aic": bool(value["AIC"]),
                "b1a": bool(value["B1A"]),
                "b1b": value["B1B"],
            }
        else:
            raise AssertionError(f"no pyobelix mapping for I048/{item}: {value}")
    return out


def _obelix_034(r: dict[str, Any]) -> dict[str, Any]:
    names = {"000": "message_type", "030": "time_of_day"}
    names |= {"020": "sector_number_deg", "041": "antenna_rotation_period_s"}
    out: dict[str, Any] = {"cat": 34}
    for item, value in r.items():
        if item == "010":
            out |= {"sac": value["SAC"], "sic": value["SIC"]}
        elif item in names:
            out[names[item]] = value
        else:
            raise AssertionError(f"no pyobelix mapping for I034/{item}: {value}")
    return out


def test_pyobelix_agrees_on_every_radar_datagram(simulated: Simulated) -> None:
    pyobelix = pytest.importorskip(
        "pyobelix", reason="pyobelix is in the test extra: pip install -e '.[test]'"
    )
    seen: Counter[str] = Counter()
    for d in simulated.datagrams:
        if d.source not in RADARS:
            continue
        ours = [(b.cat, r) for b in _blocks(d.payload) for r in b.records]
        theirs = list(pyobelix.iter_records(d.payload, strict=True))
        assert len(theirs) == len(ours)
        for (cat, record), other in zip(ours, theirs, strict=True):
            expected = _obelix_048(record) if cat == 48 else _obelix_034(record)
            assert dict(other) == expected, (d.source, d.time, record)
            seen.update(f"{cat}/{item}" for item in record)
            if cat == 34:
                seen[f"34/type{record['000']}"] += 1
    # The comparison covered what matters: positions, times, codes, Mode S, service messages.
    for what in ("48/140", "48/040", "48/070", "48/090", "48/220", "48/240", "48/250"):
        assert seen[what] > 100, what
    assert seen["34/type1"] >= 3 * 5 and seen["34/type2"] > 100 and seen["34/041"] >= 15


# ---------------------------------------------------------------------------
# libasterix, in a virtual environment of its own
# ---------------------------------------------------------------------------

LIBASTERIX_SCRIPT = textwrap.dedent(
    '''
    """Every record of a raw ASTERIX capture as a JSON line, decoded by libasterix."""
    import json
    import sys

    from asterix import base
    from asterix import generated as gen

    SPECS = {48: gen.Cat_048_1_32, 34: gen.Cat_034_1_29, 21: gen.Cat_021_2_7}


    def value(var):
        if isinstance(var, base.Element):
            content = type(var).cv_rule.cv_content
            if issubclass(content, base.ContentQuantity):
                return var.content.as_quantity()
            if issubclass(content, base.ContentString):
                return var.content.as_string()
            if issubclass(content, base.ContentInteger):
                return var.content.as_integer()
            return var.content.as_uint()
        if isinstance(var, base.Group):
            return {i.arg.cv_name: nonspare(i.arg) for i in var.arg if isinstance(i, base.Item)}
        if isinstance(var, base.Extended):
            return {
                i.arg.cv_name: nonspare(i.arg)
                for part in var.arg
                for i in part
                if isinstance(i, base.Item)
            }
        if isinstance(var, base.Repetitive):
            return [value(x) for x in var.get_list()]
        if isinstance(var, base.Compound):
            return {name: nonspare(nsp) for name, nsp in var.arg.items()}
        if isinstance(var, base.Explicit):
            return {"bytes": var.get_bytes().hex()}
        raise TypeError(f"unexpected libasterix variation {type(var)}")


    def nonspare(nsp):
        return value(nsp.variation)


    def main():
        data = open(sys.argv[1], "rb").read()
        pos = 0
        while pos < len(data):
            end = pos + int.from_bytes(data[pos + 1 : pos + 3], "big")
            blocks = base.RawDatablock.parse(base.Bits.from_bytes(data[pos:end]))
            if isinstance(blocks, ValueError):
                raise blocks
            for block in blocks:
                cat = block.get_category()
                records = SPECS[cat].cv_uap.parse(block.get_raw_records())
                if isinstance(records, ValueError):
                    raise records
                for index, record in enumerate(records):
                    items = {name: nonspare(n) for name, n in record.items_regular.items()}
                    line = {"offset": pos, "index": index, "cat": cat, "items": items}
                    print(json.dumps(line))
            pos = end


    main()
    '''
)


def _venv_python(venv: Path) -> Path:
    return venv / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def _libasterix_ready(python: Path) -> bool:
    if not python.exists():
        return False
    check = subprocess.run(
        [
            str(python),
            "-I",
            "-c",
            "import importlib.metadata as m, asterix.generated; print(m.version('libasterix'))",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return check.returncode == 0 and check.stdout.strip() == LIBASTERIX.split("==")[1]


@pytest.fixture(scope="module")
def libasterix_python(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The python of a virtual environment holding libasterix, made on first use."""
    kept = os.environ.get("TRACKER_TEST_VENVS")
    if kept and Path(kept).is_dir():
        venv = Path(kept) / "libasterix"
    else:
        venv = tmp_path_factory.mktemp("venvs") / "libasterix"
    python = _venv_python(venv)
    if _libasterix_ready(python):
        return python
    steps = [
        [sys.executable, "-m", "venv", "--clear", str(venv)],
        [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", LIBASTERIX],
    ]
    for step in steps:
        try:
            done = subprocess.run(step, capture_output=True, text=True, timeout=PIP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pytest.skip(f"{LIBASTERIX} could not be installed: {step[2:]} timed out")
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            pytest.skip(
                f"{LIBASTERIX} could not be installed in {venv} (no network or no PyPI?): "
                + " | ".join(tail)
            )
    assert _libasterix_ready(python), f"{LIBASTERIX} installed in {venv} but does not import"
    return python


def _normalised(cat: int, items: dict[str, Any]) -> dict[str, Any]:
    """libasterix's values in our codec's representation: addresses and Comm-B data are
    unsigned integers there, upper-case hex here."""
    out = dict(items)
    for category, address in ((48, "220"), (21, "080")):
        if cat == category and address in out:
            out[address] = f"{out[address]:06X}"
    if cat == 48 and "250" in out:
        out["250"] = [m | {"MBDATA": f"{m['MBDATA']:014X}"} for m in out["250"]]
    return out


def _same(ours: Any, theirs: Any, where: str) -> None:
    if isinstance(ours, dict):
        assert isinstance(theirs, dict) and ours.keys() == theirs.keys(), (where, ours, theirs)
        for key in ours:
            _same(ours[key], theirs[key], f"{where}/{key}")
    elif isinstance(ours, list):
        assert isinstance(theirs, list) and len(ours) == len(theirs), (where, ours, theirs)
        for i, (a, b) in enumerate(zip(ours, theirs, strict=True)):
            _same(a, b, f"{where}[{i}]")
    elif isinstance(ours, float) or isinstance(theirs, float):
        assert math.isclose(ours, theirs, rel_tol=1e-12, abs_tol=1e-12), (where, ours, theirs)
    else:
        assert ours == theirs, (where, ours, theirs)


@pytest.mark.slow
def test_libasterix_agrees_on_the_raw_capture(
    simulated: Simulated, libasterix_python: Path, tmp_path: Path
) -> None:
    script = tmp_path / "libasterix_decode.py"
    script.write_text(LIBASTERIX_SCRIPT, encoding="utf-8")
    # Isolated mode and another working directory: the repository's asterix must not load.
    done = subprocess.run(
        [str(libasterix_python), "-I", str(script), str(simulated.raw)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    theirs = {}
    for line in done.stdout.splitlines():
        entry = json.loads(line)
        theirs[entry["offset"], entry["index"]] = (entry["cat"], entry["items"])

    ours = {}
    for unit in read_file(simulated.raw):
        assert isinstance(unit, Datagram), unit
        for block in _blocks(unit.payload, unit.offset):
            for index, record in enumerate(block.records):
                ours[block.offset, index] = (block.cat, record)
    assert ours.keys() == theirs.keys()

    fields: Counter[str] = Counter()
    for key, (cat, record) in ours.items():
        other_cat, other = theirs[key]
        assert other_cat == cat
        _same(record, _normalised(cat, other), f"CAT{cat:03d} record {key}")
        fields.update(f"{cat}/{item}" for item in record)
    for what in ("48/010", "48/140", "48/040", "48/070", "48/090", "48/220", "48/250"):
        assert fields[what] > 100, what
    for what in ("34/000", "34/030", "21/080", "21/131", "21/073"):
        assert fields[what] > 50, what
