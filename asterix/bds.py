"""Mode S Comm-B registers BDS 4,0 / 5,0 / 6,0 as carried in ASTERIX I048/250.

I048/250 repeats (MBDATA: 56 bits, BDS1: 4 bits, BDS2: 4 bits); this module turns one
MBDATA integer into named engineering values and back.

Layout source: ICAO Doc 9871 (Technical Provisions for Mode S Services and Extended
Squitter), Appendix A, Tables A-2-64 (BDS 4,0), A-2-80 (BDS 5,0) and A-2-96 (BDS 6,0),
as reproduced in Annex 10 Vol III. MB bit 1 is the most significant bit of the 56-bit
integer. Every position, width and LSB below was cross-checked against two independent
open decoders that follow the same tables: pyModeS (junzis/pyModeS, ``bds40.py``,
``bds50.py``, ``bds60.py``, both the 1-indexed v2 and the 0-indexed v3 code) and rs1090
(xoolive/rs1090, ``decode/bds/bds40.rs``, ``bds50.rs``, ``bds60.rs``). They agree with
each other and with Doc 9871 on all fields used here.

Signed fields are two's complement over (sign bit + value bits), as Doc 9871 gives their
ranges as e.g. [-16384, +16352] ft/min. pyModeS v2 and rs1090 additionally map an
all-ones vertical rate to 0 and an all-ones track angle rate to "unavailable"; Doc 9871
has no such rule, so this module does not either (pyModeS v3 agrees).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from fractions import Fraction
from typing import Final, NamedTuple

__all__ = [
    "LAYOUTS",
    "MB_BITS",
    "Field",
    "Layout",
    "decode_bds40",
    "decode_bds50",
    "decode_bds60",
    "decode_mb",
    "encode_bds40",
    "encode_bds50",
    "encode_bds60",
    "infer_register",
]

MB_BITS: Final = 56
_MB_LIMIT: Final = 1 << MB_BITS


class Field(NamedTuple):
    """One value subfield of a Comm-B register; bit numbers are MB bits (1 = MSB)."""

    name: str
    status_bit: int
    sign_bit: int | None
    first_bit: int
    width: int
    lsb: Fraction
    offset: Fraction
    unit: str  # "bool" and "code" select the Python type; otherwise informational
    # Range a genuine report stays in; used only by infer_register, never to reject a
    # register whose identity the radar already stated in BDS1/BDS2.
    plausible: tuple[Fraction, Fraction] | None = None
    # Sign + value bits span exactly 360 deg, so the encoding wraps instead of saturating.
    wraps_360: bool = False
    # Fields that share one status bit (the 4,0 MCP/FCU mode bits) share one status key.
    status_key: str | None = None

    @property
    def key(self) -> str:
        return self.status_key if self.status_key is not None else f"{self.name}_status"


class Layout(NamedTuple):
    fields: tuple[Field, ...]
    reserved: tuple[tuple[int, int], ...]  # inclusive MB bit ranges that must be zero
    # Cross-field plausibility rules for infer_register, over decoded values.
    checks: tuple[Callable[[Mapping[str, object]], bool], ...] = ()


def _q(num: int, den: int = 1) -> Fraction:
    return Fraction(num, den)


_ONE = _q(1)
_ZERO = _q(0)
_MACH_LSB = Fraction("2.048") / 512


def _gs_tas_agree(values: Mapping[str, object]) -> bool:
    # Wind rarely exceeds 200 kt, so ground speed and TAS far apart mean "not a 5,0";
    # the same rule is in pyModeS is50 and rs1090 read_tas.
    gs, tas = values.get("ground_speed_kt"), values.get("true_airspeed_kt")
    if isinstance(gs, int) and isinstance(tas, int):
        return abs(gs - tas) <= 200
    return True


_MODE = "mode_status"

# fmt: off
LAYOUTS: Final[Mapping[str, Layout]] = {
    # Doc 9871 Table A-2-64, selected vertical intention.
    "4,0": Layout(
        fields=(
            #     name                        status sign first width lsb       offset   unit
            Field("selected_altitude_mcp_ft",      1, None,  2, 12, _q(16),    _ZERO,   "ft",
                  plausible=(_ZERO, _q(52_000))),
            Field("selected_altitude_fms_ft",     14, None, 15, 12, _q(16),    _ZERO,   "ft",
                  plausible=(_ZERO, _q(52_000))),
            Field("baro_pressure_setting_mb",     27, None, 28, 12, _q(1, 10), _q(800), "mb"),
            Field("vnav_mode",                    48, None, 49,  1, _ONE,      _ZERO,   "bool",
                  status_key=_MODE),
            Field("alt_hold_mode",                48, None, 50,  1, _ONE,      _ZERO,   "bool",
                  status_key=_MODE),
            Field("approach_mode",                48, None, 51,  1, _ONE,      _ZERO,   "bool",
                  status_key=_MODE),
            # 0 unknown, 1 aircraft altitude, 2 FCU/MCP selected altitude, 3 FMS selected.
            Field("target_altitude_source",       54, None, 55,  2, _ONE,      _ZERO,   "code"),
        ),
        reserved=((40, 47), (52, 53)),
    ),
    # Doc 9871 Table A-2-80, track and turn report.
    "5,0": Layout(
        fields=(
            # Doc range is +-90 deg; airliners stay within +-50 (pyModeS v3, rs1090 limit).
            Field("roll_deg",                      1,    2,  3,  9, _q(45, 256), _ZERO, "deg",
                  plausible=(_q(-50), _q(50))),
            Field("track_angle_deg",              12,   13, 14, 10, _q(90, 512), _ZERO, "deg",
                  wraps_360=True),
            Field("ground_speed_kt",              24, None, 25, 10, _q(2),       _ZERO, "kt",
                  plausible=(_ZERO, _q(600))),
            Field("track_angle_rate_deg_s",       35,   36, 37,  9, _q(8, 256),  _ZERO, "deg/s"),
            Field("true_airspeed_kt",             46, None, 47, 10, _q(2),       _ZERO, "kt",
                  plausible=(_ZERO, _q(600))),
        ),
        reserved=(),
        checks=(_gs_tas_agree,),
    ),
    # Doc 9871 Table A-2-96, heading and speed report.
    "6,0": Layout(
        fields=(
            Field("magnetic_heading_deg",          1,    2,  3, 10, _q(90, 512), _ZERO, "deg",
                  wraps_360=True),
            Field("indicated_airspeed_kt",        13, None, 14, 10, _ONE,        _ZERO, "kt",
                  plausible=(_ZERO, _q(500))),
            Field("mach",                         24, None, 25, 10, _MACH_LSB,   _ZERO, "Mach",
                  plausible=(_ZERO, _ONE)),
            Field("baro_vertical_rate_ft_min",    35,   36, 37,  9, _q(32),      _ZERO, "ft/min",
                  plausible=(_q(-6000), _q(6000))),
            Field("inertial_vertical_rate_ft_min", 46,  47, 48,  9, _q(32),      _ZERO, "ft/min",
                  plausible=(_q(-6000), _q(6000))),
        ),
        reserved=(),
    ),
}
# fmt: on


def _bits(mb: int, first: int, width: int) -> int:
    return (mb >> (MB_BITS - first - width + 1)) & ((1 << width) - 1)


def _place(value: int, first: int, width: int) -> int:
    return value << (MB_BITS - first - width + 1)


def _check_mb(mb: int) -> None:
    if not 0 <= mb < _MB_LIMIT:
        raise ValueError(f"MB data must be an unsigned 56-bit integer, got {mb:#x}")


def _pattern_width(field: Field) -> int:
    return field.width + (field.sign_bit is not None)


def _read_pattern(field: Field, mb: int) -> int:
    """Sign bit and value bits as one integer (sign on top), whatever their positions."""
    pattern = _bits(mb, field.first_bit, field.width)
    if field.sign_bit is not None:
        pattern |= _bits(mb, field.sign_bit, 1) << field.width
    return pattern


def _exact_value(field: Field, pattern: int) -> Fraction:
    steps = pattern
    if field.sign_bit is not None and not field.wraps_360 and pattern >> field.width:
        steps -= 1 << _pattern_width(field)
    # A wrapping angle read as unsigned over sign + value bits is already in [0, 360).
    return steps * field.lsb + field.offset


def _typed(field: Field, exact: Fraction) -> object:
    if field.unit == "bool":
        return bool(exact)
    # The type follows the grid, not the value, so 0 deg is still a float.
    if field.lsb.denominator == 1 and field.offset.denominator == 1:
        return int(exact)
    return float(exact)


def _decode(register: str, mb: int) -> dict[str, object]:
    _check_mb(mb)
    out: dict[str, object] = {"register": register}
    for field in LAYOUTS[register].fields:
        status = _bits(mb, field.status_bit, 1)
        exact = _exact_value(field, _read_pattern(field, mb))
        out[field.name] = _typed(field, exact) if status else None
        out[field.key] = status
    return out


def _round_half_away(q: Fraction) -> int:
    n = math.floor(abs(q) + Fraction(1, 2))
    return n if q >= 0 else -n


def _quantise(field: Field, value: object) -> int:
    """Return the sign+value bit pattern for one field value.

    Magnitudes beyond the register range saturate, as Doc 9871 asks of transponders
    ("the maximum allowable value in the correct positive or negative sense shall be
    used"); values with no meaning in the field's sense raise ValueError.
    """
    if field.unit == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"{field.name} must be a bool, got {value!r}")
        return int(value)
    if field.unit == "code":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{field.name} must be an int code, got {value!r}")
        if not 0 <= value < 1 << field.width:
            raise ValueError(f"{field.name} must be in 0..{(1 << field.width) - 1}, got {value}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{field.name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{field.name} must be finite, got {value!r}")
    x = Fraction(value)
    span = 1 << _pattern_width(field)
    if field.wraps_360:
        if not -180 <= x <= 360:
            raise ValueError(f"{field.name} must be within [-180, 360] deg, got {value}")
        return _round_half_away((x - field.offset) / field.lsb) % span
    steps = _round_half_away((x - field.offset) / field.lsb)
    if field.sign_bit is None:
        if steps < 0:
            raise ValueError(
                f"{field.name} must be >= {float(field.offset)} {field.unit}, got {value}"
            )
        return min(steps, span - 1)
    half = span // 2
    return max(-half, min(steps, half - 1)) % span


def _encode(register: str, fields: Mapping[str, object]) -> int:
    layout = LAYOUTS[register]
    names = {f.name for f in layout.fields}
    status_keys = {f.key for f in layout.fields}
    unknown = sorted(set(fields) - names - status_keys - {"register"})
    if unknown:
        reg = register.replace(",", "")
        raise TypeError(f"encode_bds{reg}() got unknown field(s): {', '.join(unknown)}")
    if fields.get("register", register) != register:
        raise ValueError(f"register {fields['register']!r} given to the {register} encoder")

    groups: dict[str, list[Field]] = {}
    for field in layout.fields:
        groups.setdefault(field.key, []).append(field)

    mb = 0
    for key, members in groups.items():
        present = [fields.get(f.name) is not None for f in members]
        if any(present) and not all(present):
            missing = [f.name for f, p in zip(members, present, strict=True) if not p]
            raise ValueError(
                f"{', '.join(f.name for f in members)} share status bit "
                f"{members[0].status_bit}: give all or none (missing {', '.join(missing)})"
            )
        status = int(all(present))
        claimed = fields.get(key)
        if claimed is not None and claimed not in (0, 1):
            raise ValueError(f"{key} must be 0 or 1, got {claimed!r}")
        if claimed is not None and claimed != status:
            raise ValueError(f"{key}={claimed} contradicts the value(s) given")
        if not status:
            continue
        mb |= _place(1, members[0].status_bit, 1)
        for field in members:
            pattern = _quantise(field, fields[field.name])
            mb |= _place(pattern & ((1 << field.width) - 1), field.first_bit, field.width)
            if field.sign_bit is not None:
                mb |= _place(pattern >> field.width, field.sign_bit, 1)
    return mb


def _plausible(register: str, mb: int) -> bool:
    layout = LAYOUTS[register]
    for first, last in layout.reserved:
        if _bits(mb, first, last - first + 1):
            return False
    values = _decode(register, mb)
    for field in layout.fields:
        pattern = _read_pattern(field, mb)
        if not values[field.key]:
            # Doc 9871 A.2.2.2: an invalid parameter is sent as all zeros, so any set bit
            # under a zero status says this MB is some other register.
            if pattern:
                return False
            continue
        if field.plausible is not None:
            lo, hi = field.plausible
            if not lo <= _exact_value(field, pattern) <= hi:
                return False
    return all(check(values) for check in layout.checks)


def decode_mb(mb: int, bds1: int, bds2: int) -> dict[str, object] | None:
    """Decode one I048/250 repetition; None for registers this module does not know.

    BDS1=BDS2=0 (register not identified by the radar) also gives None: see
    infer_register.
    """
    if not (0 <= bds1 <= 15 and 0 <= bds2 <= 15):
        raise ValueError(f"BDS1/BDS2 are 4-bit values, got {bds1}, {bds2}")
    register = f"{bds1:X},{bds2:X}"
    if register not in LAYOUTS:
        _check_mb(mb)
        return None
    return _decode(register, mb)


def decode_bds40(mb: int) -> dict[str, object]:
    """BDS 4,0 selected vertical intention; each value is None when its status is 0."""
    return _decode("4,0", mb)


def decode_bds50(mb: int) -> dict[str, object]:
    """BDS 5,0 track and turn report; track angle in [0, 360) deg."""
    return _decode("5,0", mb)


def decode_bds60(mb: int) -> dict[str, object]:
    """BDS 6,0 heading and speed report; magnetic heading in [0, 360) deg."""
    return _decode("6,0", mb)


def encode_bds40(**fields: object) -> int:
    """Inverse of decode_bds40; absent or None fields are sent with status 0.

    The three MCP/FCU mode flags share status bit 48: give all three or none.
    """
    return _encode("4,0", fields)


def encode_bds50(**fields: object) -> int:
    """Inverse of decode_bds50; track angle accepted in [-180, 360] deg."""
    return _encode("5,0", fields)


def encode_bds60(**fields: object) -> int:
    """Inverse of decode_bds60; magnetic heading accepted in [-180, 360] deg."""
    return _encode("6,0", fields)


def infer_register(mb: int) -> str | None:
    """Guess the register of MB data whose BDS1/BDS2 are 0 (broadcast or unknown).

    Returns "4,0", "5,0" or "6,0" only when exactly that one passes the pyModeS/rs1090
    style checks (status/zero consistency, reserved bits zero, value ranges); 5,0 and
    6,0 share most status bit positions, so a genuinely ambiguous MB gives None.
    """
    _check_mb(mb)
    if mb == 0:
        return None
    candidates = [register for register in LAYOUTS if _plausible(register, mb)]
    return candidates[0] if len(candidates) == 1 else None
