"""Write recordings/demo_dual_lan.pcap: a small synthetic two-radar capture for the demo.

Two rotating radars (4 s and 5 s antenna periods) see three aircraft flying straight
for two minutes; each scan sends CAT034 north markers and sector crossings and CAT048
plots per 45-degree sector, every datagram twice (redundant LANs A and B), as a real
radar station does. The geometry is a flat-earth approximation: this capture exists to
show the decoder at work, not to judge a tracker (the scenario simulator does that).

Run: python recordings/make_demo_capture.py   (the output is deterministic)
"""

from __future__ import annotations

import math
from pathlib import Path

from asterix import encode_block
from asterix.containers import write_pcap

START_TOD = 43200.0  # 12:00:00 UTC
DATE_POSIX = 1_767_225_600.0  # 2026-01-01T00:00:00Z
DURATION = 120.0
SECTORS = 8

RADARS = [
    # (SAC, SIC, east km, north km, period s, multicast group on LAN A, on LAN B)
    (25, 11, 0.0, 0.0, 4.0, "232.1.1.11", "232.2.1.11"),
    (25, 12, 80.0, 30.0, 5.0, "232.1.1.12", "232.2.1.12"),
]
AIRCRAFT = [
    # (address, callsign, Mode 3/A, FL, east km, north km, speed kt, course deg)
    ("3C660C", "DLH65A  ", "1000", 330.0, -40.0, 60.0, 450.0, 120.0),
    ("4BAACD", "THY9TX  ", "2303", 360.0, 90.0, -20.0, 470.0, 280.0),
    ("501D2A", "CTN471  ", "4621", 120.0, 20.0, 10.0, 250.0, 45.0),
]
KT_TO_KM_S = 1.852 / 3600.0
NM = 1.852


def _position(aircraft: tuple[str, str, str, float, float, float, float, float], t: float):
    _, _, _, _, east, north, speed, course = aircraft
    d = speed * KT_TO_KM_S * t
    c = math.radians(course)
    return east + d * math.sin(c), north + d * math.cos(c)


def _plot(radar, aircraft, t: float, tod: float) -> tuple[float, dict[str, object]] | None:
    sac, sic, rx, ry, *_ = radar
    east, north = _position(aircraft, t)
    dx, dy = east - rx, north - ry
    rho_nm = math.hypot(dx, dy) / NM
    theta = math.degrees(math.atan2(dx, dy)) % 360.0
    address, callsign, code, fl, *_rest, speed, course = aircraft
    record = {
        "010": {"SAC": sac, "SIC": sic},
        "140": round(tod * 128) / 128,
        "020": {"TYP": 5},
        "040": {
            "RHO": round(rho_nm * 256) / 256,
            "THETA": round(theta / (360 / 65536)) * (360 / 65536),
        },
        "070": {"MODE3A": code},
        "090": {"FL": fl},
        "220": address,
        "240": callsign,
        "200": {
            "GSP": round(speed / 3600 * 2**14) / 2**14,
            "HDG": round(course / (360 / 65536)) * (360 / 65536),
        },
        "230": {"COM": 1, "MSSC": 1, "ARC": 1, "AIC": 1, "B1A": 1, "B1B": 5},
    }
    return theta, record


def main() -> None:
    datagrams = []
    for radar in RADARS:
        sac, sic, _, _, period, group_a, group_b = radar
        scan = 0
        while (scan_start := scan * period) < DURATION:
            for sector in range(SECTORS):
                t_end = scan_start + (sector + 1) * period / SECTORS
                tod = START_TOD + t_end
                plots = []
                for aircraft in AIRCRAFT:
                    theta, _ = _plot(radar, aircraft, t_end, tod)
                    if int(theta // (360 / SECTORS)) == sector:
                        # Detection time: when the beam crossed the aircraft's azimuth.
                        t_seen = scan_start + theta / 360 * period
                        plots.append(_plot(radar, aircraft, t_seen, START_TOD + t_seen)[1])
                service = {
                    "010": {"SAC": sac, "SIC": sic},
                    "000": 1 if sector == 0 else 2,
                    "030": round(tod * 128) / 128,
                    "020": (sector + 1) % SECTORS * (360 / SECTORS),
                }
                if sector == 0:
                    service["041"] = period
                payload = encode_block(34, [service])
                if plots:
                    payload += encode_block(48, plots)
                source = ("10.17.58.183", 50000 + sic)
                datagrams.append((DATE_POSIX + tod + 0.05, source, (group_a, 8600), payload))
                datagrams.append((DATE_POSIX + tod + 0.0501, source, (group_b, 8600), payload))
            scan += 1
    datagrams.sort(key=lambda d: d[0])
    out = Path(__file__).with_name("demo_dual_lan.pcap")
    count = write_pcap(out, datagrams)
    print(f"wrote {out} with {count} packets")


if __name__ == "__main__":
    main()
