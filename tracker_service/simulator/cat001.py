"""A radar's output in CAT001/CAT002 instead of CAT048/CAT034, as older radars send it.

The radar model measures and builds CAT048 records; a radar with ``asterix = "cat001"``
sends each as the CAT001 plot record an older radar would send for the same detection:
the same source, position, Mode 3/A and Mode C, with what CAT001 cannot carry left out
(Mode S address, callsign, registers) and I140 cut to the truncated I141 (the time of day
modulo 512 s). Service messages go out as CAT002, whose items match CAT034's.
"""

from __future__ import annotations

from typing import Any

CAT048_TO_SSRPSR = {0: 0, 1: 1, 2: 2, 3: 3, 4: 2, 5: 2, 6: 3, 7: 3}
"""CAT048 I020 TYP -> CAT001 I020 SSRPSR: Mode S all-call and roll-call replies are
secondary detections, and with a primary one, combined."""
RHO_LSB_NM = 1 / 128
RHO_MAX_NM = 65535 / 128
TICKS_PER_S = 128


def truncated_time(time_of_day: float) -> float:
    """I141: the time of day in 1/128 s, its low 16 bits."""
    return (round(time_of_day * TICKS_PER_S) & 0xFFFF) / TICKS_PER_S


def cat001_plot(record: dict[str, Any]) -> dict[str, Any]:
    """The CAT001 plot record of a CAT048 plot record (see the module docstring)."""
    descriptor = record["020"]
    out: dict[str, Any] = {
        "010": record["010"],
        "020": {
            "TYP": 0,
            "SIM": descriptor.get("SIM", 0),
            "SSRPSR": CAT048_TO_SSRPSR[descriptor["TYP"]],
            "ANT": 0,
            "SPI": descriptor.get("SPI", 0),
            "RAB": descriptor.get("RAB", 0),
        },
    }
    if descriptor.get("TST"):
        out["020"].update(TST=1, DS1DS2=0, ME=0, MI=0)
    polar = record["040"]
    extended = record.get("RE", {}).get("ERR") if isinstance(record.get("RE"), dict) else None
    rho = polar["RHO"] if extended is None else extended
    out["040"] = {
        "RHO": min(round(rho / RHO_LSB_NM) * RHO_LSB_NM, RHO_MAX_NM),
        "THETA": polar["THETA"],
    }
    if "070" in record:
        out["070"] = record["070"]
    if "090" in record:
        mode_c = record["090"]
        out["090"] = {"V": mode_c["V"], "G": mode_c["G"], "HGT": mode_c["FL"]}
    if "140" in record:
        out["141"] = truncated_time(record["140"])
    return out
