"""Reading Pacejka tyre property files (`.tir`, TNO/MF-Tyre format) into a packed parameter array.

File format
-----------
ASCII, one item per line::

    [SECTION]                          $ a section header
    KEY        = 1.234e-3              $ a number, then an optional comment
    TYRESIDE   = 'LEFT'                $ a quoted string ('...' or "...")
    ! a comment line                   (so is one starting with $, and a blank line)
    {radial  width}                    (MF-Swift tables, e.g. [SHAPE]: a {header} line, then rows of
     1.0     0.0                        numbers; kept as read, not used by the kernels)

`$` and `!` start a comment anywhere outside quotes. Keys and section names are case-insensitive
(stored upper case). Numbers accept Fortran `D` exponents. A key may appear once per section.

What is read (MF 5.2 with the MF 6.1 names where they differ)
------------------------------------------------------------
The keys of `SCHEMA` below: [UNITS] (SI only), [MODEL] (FITTYP, LONGVL, VXLOW, TYRESIDE),
[DIMENSION], [VERTICAL], [STRUCTURAL] (MF 6.1: carcass stiffnesses and low-speed damping),
[SCALING_COEFFICIENTS], [LONGITUDINAL_COEFFICIENTS], [LATERAL_COEFFICIENTS],
[ALIGNING_COEFFICIENTS], [ROLLING_COEFFICIENTS]. A key found in another section than the expected one
is still accepted (some tools misplace e.g. PTX1); every other key is kept in `sections` and listed in
`ignored` (MF 6.1 pressure, turn-slip, overturning, Swift items: not part of this subset). MF 6.1/6.2
files (FITTYP 61/62) load and are evaluated with the MF 5.2 equations of the shared subset.

Missing optional keys take the MF convention: 0 for coefficients, 1 for scaling factors (listed in
`defaulted`); a few structural items default to the TNO example values (see SCHEMA). Missing required
keys, malformed lines and values out of their physical range raise `ConfigError` naming the file,
the section/key or line, the value and the allowed range.

Sign convention: ISO/TYDEX (the usual one of .tir files): a positive slip angle (the contact point
moving to the left of the wheel heading) gives a negative lateral force, hence PKY1 < 0.

Packed array
------------
`TyreProperties.params` is a float64 array read by the numba kernels; `P_<KEY>` are its indices,
defined once below (`PARAM_NAMES[i]` is the key of index i). Slots after the file keys hold derived
values for the linearised model (`P_LIN_*`, computed here at Fz = FNOMIN, gamma = 0).
"""
from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np

from rtsim.configfile import note_read
from rtsim.errors import ConfigError

# ---- index constants of the packed parameter array (the one place they are defined) ----------------
# [DIMENSION], [VERTICAL], [MODEL]
P_FNOMIN = 0
P_UNLOADED_RADIUS = 1
P_VERTICAL_STIFFNESS = 2
P_VERTICAL_DAMPING = 3
P_BREFF = 4
P_DREFF = 5
P_FREFF = 6
P_LONGVL = 7
P_VXLOW = 8
# [SCALING_COEFFICIENTS]
P_LFZO = 9
P_LCX = 10
P_LMUX = 11
P_LEX = 12
P_LKX = 13
P_LHX = 14
P_LVX = 15
P_LGAX = 16
P_LCY = 17
P_LMUY = 18
P_LEY = 19
P_LKY = 20
P_LHY = 21
P_LVY = 22
P_LGAY = 23
P_LTR = 24
P_LRES = 25
P_LGAZ = 26
P_LXAL = 27
P_LYKA = 28
P_LVYKA = 29
P_LS = 30
P_LSGKP = 31
P_LSGAL = 32
P_LMX = 33
P_LMY = 34
# [LONGITUDINAL_COEFFICIENTS]
P_PCX1 = 35
P_PDX1 = 36
P_PDX2 = 37
P_PDX3 = 38
P_PEX1 = 39
P_PEX2 = 40
P_PEX3 = 41
P_PEX4 = 42
P_PKX1 = 43
P_PKX2 = 44
P_PKX3 = 45
P_PHX1 = 46
P_PHX2 = 47
P_PVX1 = 48
P_PVX2 = 49
P_RBX1 = 50
P_RBX2 = 51
P_RBX3 = 52
P_RCX1 = 53
P_REX1 = 54
P_REX2 = 55
P_RHX1 = 56
P_PTX1 = 57
P_PTX2 = 58
P_PTX3 = 59
# [LATERAL_COEFFICIENTS]
P_PCY1 = 60
P_PDY1 = 61
P_PDY2 = 62
P_PDY3 = 63
P_PEY1 = 64
P_PEY2 = 65
P_PEY3 = 66
P_PEY4 = 67
P_PKY1 = 68
P_PKY2 = 69
P_PKY3 = 70
P_PHY1 = 71
P_PHY2 = 72
P_PHY3 = 73
P_PVY1 = 74
P_PVY2 = 75
P_PVY3 = 76
P_PVY4 = 77
P_RBY1 = 78
P_RBY2 = 79
P_RBY3 = 80
P_RCY1 = 81
P_REY1 = 82
P_REY2 = 83
P_RHY1 = 84
P_RHY2 = 85
P_RVY1 = 86
P_RVY2 = 87
P_RVY3 = 88
P_RVY4 = 89
P_RVY5 = 90
P_RVY6 = 91
P_PTY1 = 92
P_PTY2 = 93
# [ALIGNING_COEFFICIENTS]
P_QBZ1 = 94
P_QBZ2 = 95
P_QBZ3 = 96
P_QBZ4 = 97
P_QBZ5 = 98
P_QBZ9 = 99
P_QBZ10 = 100
P_QCZ1 = 101
P_QDZ1 = 102
P_QDZ2 = 103
P_QDZ3 = 104
P_QDZ4 = 105
P_QDZ6 = 106
P_QDZ7 = 107
P_QDZ8 = 108
P_QDZ9 = 109
P_QEZ1 = 110
P_QEZ2 = 111
P_QEZ3 = 112
P_QEZ4 = 113
P_QEZ5 = 114
P_QHZ1 = 115
P_QHZ2 = 116
P_QHZ3 = 117
P_QHZ4 = 118
P_SSZ1 = 119
P_SSZ2 = 120
P_SSZ3 = 121
P_SSZ4 = 122
# [ROLLING_COEFFICIENTS]
P_QSY1 = 123
P_QSY2 = 124
P_QSY3 = 125
P_QSY4 = 126
# [STRUCTURAL] (MF 6.1 names; used by the transient-slip kernels)
P_LONGITUDINAL_STIFFNESS = 127
P_LATERAL_STIFFNESS = 128
P_DAMP_RESIDUAL = 129
P_DAMP_VLOW = 130
# derived at load time for rtsim.vehicle.kit.tyre.linear (Fz = FNOMIN, gamma = 0, no offsets)
P_LIN_CX = 131        # longitudinal slip stiffness Kxk(FNOMIN) [N]
P_LIN_CALPHA = 132    # cornering stiffness -Kya(FNOMIN) > 0 [N/rad]
P_LIN_MUX = 133       # PDX1 * LMUX
P_LIN_MUY = 134       # |PDY1| * LMUY
P_LIN_TRAIL = 135     # pneumatic trail at zero slip, FNOMIN [m]
N_PARAMS = 136

PARAM_NAMES: tuple[str, ...] = tuple(
    name[2:] for name, _ in sorted(((n, v) for n, v in globals().items()
                                    if n.startswith("P_") and isinstance(v, int)), key=lambda kv: kv[1]))
assert len(PARAM_NAMES) == N_PARAMS and all(globals()["P_" + n] == i for i, n in enumerate(PARAM_NAMES))

# ---- what the file may hold -----------------------------------------------------------------------
REQUIRED = object()


@dataclass(frozen=True)
class Key:
    section: str
    default: object                    # REQUIRED, or the value used when missing
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False              # True: lo itself excluded
    hi_open: bool = False
    note: str = ""                     # why the range (appended to the error message)

    def allowed(self) -> str:
        lo = "-inf" if self.lo == -math.inf else f"{self.lo:g}"
        hi = "inf" if self.hi == math.inf else f"{self.hi:g}"
        return f"{'(' if self.lo_open or self.lo == -math.inf else '['}{lo}, {hi}" \
               f"{')' if self.hi_open or self.hi == math.inf else ']'}"

    def ok(self, v: float) -> bool:
        if not math.isfinite(v):
            return False
        if v < self.lo or (self.lo_open and v == self.lo):
            return False
        return not (v > self.hi or (self.hi_open and v == self.hi))


DIM, VERT, MODEL, STRUCT = "DIMENSION", "VERTICAL", "MODEL", "STRUCTURAL"
SCAL, LONG, LAT, ALIGN, ROLL = ("SCALING_COEFFICIENTS", "LONGITUDINAL_COEFFICIENTS", "LATERAL_COEFFICIENTS",
                                "ALIGNING_COEFFICIENTS", "ROLLING_COEFFICIENTS")

SCHEMA: dict[str, Key] = {
    # [MODEL]
    "FITTYP": Key(MODEL, 6),
    "LONGVL": Key(MODEL, 16.7, 0.0, 1000.0, lo_open=True, note="reference speed, m/s"),
    "VXLOW": Key(MODEL, 1.0, 0.0, 100.0, lo_open=True, note="low-speed blending speed, m/s"),
    # [DIMENSION]
    "UNLOADED_RADIUS": Key(DIM, REQUIRED, 0.0, 2.0, lo_open=True, note="m"),
    "WIDTH": Key(DIM, 0.0, 0.0, 2.0, note="m (0: not given)"),
    "ASPECT_RATIO": Key(DIM, 0.0, 0.0, 2.0, note="(0: not given)"),
    "RIM_RADIUS": Key(DIM, 0.0, 0.0, 2.0, note="m, below UNLOADED_RADIUS (0: not given)"),
    "RIM_WIDTH": Key(DIM, 0.0, 0.0, 2.0, note="m (0: not given)"),
    # [VERTICAL]
    "FNOMIN": Key(VERT, REQUIRED, 0.0, 1e6, lo_open=True, note="N"),
    "VERTICAL_STIFFNESS": Key(VERT, REQUIRED, 0.0, 1e9, lo_open=True, note="N/m"),
    "VERTICAL_DAMPING": Key(VERT, 0.0, 0.0, 1e7, note="N*s/m"),
    "BREFF": Key(VERT, 0.0, 0.0, 100.0),
    "DREFF": Key(VERT, 0.0, 0.0, 10.0),
    "FREFF": Key(VERT, 0.0, 0.0, 10.0),
    # [STRUCTURAL] (MF 6.1): carcass stiffnesses (0: use PTX/PTY, else the default relaxation
    # lengths, see magic_formula) and damping time constants (s) of the contact deflection; the
    # defaults are the values of the TNO MF-Tyre 6.1 example file.
    "LONGITUDINAL_STIFFNESS": Key(STRUCT, 0.0, 0.0, 1e9, note="N/m"),
    "LATERAL_STIFFNESS": Key(STRUCT, 0.0, 0.0, 1e9, note="N/m"),
    "DAMP_RESIDUAL": Key(STRUCT, 0.002, 0.0, 1.0, note="s"),
    "DAMP_VLOW": Key(STRUCT, 0.001, 0.0, 1.0, note="s"),
}
_SCALING = ("LFZO LCX LMUX LEX LKX LHX LVX LGAX LCY LMUY LEY LKY LHY LVY LGAY LTR LRES LGAZ LXAL LYKA "
            "LVYKA LS LSGKP LSGAL LMX LMY").split()
for _k in _SCALING:
    # divided by: LFZO (Fz0'), LCX/LCY/LMUX/LMUY (B = K/(C D)), LMUY also in the trail slope
    _pos = _k in ("LFZO", "LCX", "LCY", "LMUX", "LMUY")
    SCHEMA[_k] = Key(SCAL, 1.0, 0.0, 100.0, lo_open=_pos, note="scaling factor")
for _k in ("PDX2 PDX3 PEX1 PEX2 PEX3 PEX4 PKX2 PKX3 PHX1 PHX2 PVX1 PVX2 RBX1 RBX2 RBX3 RCX1 REX1 REX2 "
           "RHX1 PTX2 PTX3").split():
    SCHEMA[_k] = Key(LONG, 0.0)
SCHEMA["PCX1"] = Key(LONG, REQUIRED, 0.0, 10.0, lo_open=True, note="shape factor C > 0")
SCHEMA["PDX1"] = Key(LONG, REQUIRED, 0.0, 10.0, lo_open=True, note="peak friction coefficient")
SCHEMA["PKX1"] = Key(LONG, REQUIRED, 0.0, 1000.0, lo_open=True, note="slip stiffness Kx/Fz at FNOMIN")
SCHEMA["PTX1"] = Key(LONG, 0.0, 0.0, 100.0, note="relaxation length sigma_kappa*FNOMIN/(Fz*R0) at FNOMIN")
for _k in ("PDY2 PDY3 PEY1 PEY2 PEY3 PEY4 PKY3 PHY1 PHY2 PHY3 PVY1 PVY2 PVY3 PVY4 RBY1 RBY2 RBY3 RCY1 "
           "REY1 REY2 RHY1 RHY2 RVY1 RVY2 RVY3 RVY4 RVY5 RVY6").split():
    SCHEMA[_k] = Key(LAT, 0.0)
SCHEMA["PCY1"] = Key(LAT, REQUIRED, 0.0, 10.0, lo_open=True, note="shape factor C > 0")
SCHEMA["PDY1"] = Key(LAT, REQUIRED, -10.0, 10.0, note="peak friction coefficient (sign as fitted), nonzero")
SCHEMA["PKY1"] = Key(LAT, REQUIRED, -1000.0, 0.0, hi_open=True,
                     note="ISO/TYDEX sign convention: a positive slip angle gives a negative Fy")
SCHEMA["PKY2"] = Key(LAT, REQUIRED, 0.0, 100.0, lo_open=True, note="Fz/Fz0 of peak cornering stiffness")
SCHEMA["PTY1"] = Key(LAT, 0.0, 0.0, 100.0, note="peak relaxation length sigma_alpha/R0")
SCHEMA["PTY2"] = Key(LAT, 0.0, 0.0, 100.0, note="Fz/Fz0 of peak sigma_alpha (> 0 when PTY1 > 0)")
for _k in ("QBZ1 QBZ2 QBZ3 QBZ4 QBZ5 QBZ9 QBZ10 QDZ1 QDZ2 QDZ3 QDZ4 QDZ6 QDZ7 QDZ8 QDZ9 QEZ1 QEZ2 QEZ3 "
           "QEZ4 QEZ5 QHZ1 QHZ2 QHZ3 QHZ4 SSZ1 SSZ2 SSZ3 SSZ4").split():
    SCHEMA[_k] = Key(ALIGN, 0.0)
SCHEMA["QCZ1"] = Key(ALIGN, 0.0, 0.0, 10.0, note="trail shape factor C >= 0")
for _k in ("QSY1", "QSY2", "QSY3", "QSY4"):
    SCHEMA[_k] = Key(ROLL, 0.0)
SCHEMA["QSY1"] = Key(ROLL, 0.0, 0.0, 1.0, note="rolling resistance coefficient")

#: keys kept as strings
STRING_KEYS = {"TYRESIDE": MODEL}
#: accepted FITTYP values: 5/6/21 (MF 5.x as written by MF-Tool/Adams), 52, 61/62 (MF 6.x)
FITTYPS = (5, 6, 21, 52, 61, 62)
SI_UNITS = {"LENGTH": ("meter", "metre", "m"), "FORCE": ("newton", "n"), "ANGLE": ("radians", "radian", "rad"),
            "MASS": ("kg", "kilogram"), "TIME": ("second", "sec", "s")}

assert all(n in SCHEMA for n in PARAM_NAMES if not n.startswith("LIN_"))


# ---- result --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TyreProperties:
    """A parsed property file. `params` is the packed array of the kernels (read-only)."""
    source: str
    fittyp: int
    tyreside: str
    unloaded_radius: float          # m
    width: float                    # m (0: not given)
    aspect_ratio: float
    rim_radius: float               # m (0: not given)
    rim_width: float                # m (0: not given)
    fnomin: float                   # N
    vertical_stiffness: float       # N/m
    vertical_damping: float         # N*s/m
    longvl: float                   # m/s
    vxlow: float                    # m/s
    coefficients: Mapping[str, float]           # every SCHEMA key, defaults filled in
    params: np.ndarray                          # float64 (N_PARAMS,), P_* indices
    defaulted: tuple[str, ...] = ()             # SCHEMA keys missing from the file
    ignored: tuple[str, ...] = ()               # 'SECTION.KEY' present in the file, not used here
    sections: Mapping[str, Mapping[str, object]] = field(default_factory=dict)   # as read, in order
    tables: Mapping[str, tuple[str, tuple[tuple[float, ...], ...]]] = field(default_factory=dict)

    def __getitem__(self, key: str) -> float:
        return self.coefficients[key.upper()]


# ---- parsing --------------------------------------------------------------------------------------
_SECTION_RE = re.compile(r"^\[\s*([A-Za-z0-9_]+)\s*\]$")
_KEY_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_NUM_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")
_INT_RE = re.compile(r"^[+-]?\d+$")
_WORD_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


def _strip_comment(line: str) -> str | None:
    """The line without its comment, or None for an unterminated quote."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch in "$!":
            return line[:i]
    return None if quote else line


def _value(text: str):
    """A number (int or float), a string, or None when malformed."""
    if len(text) >= 2 and text[0] in "'\"" and text[-1] == text[0] and text[0] not in text[1:-1]:
        return text[1:-1]
    if _INT_RE.match(text):
        return int(text)
    if _NUM_RE.match(text):
        return float(text.replace("d", "e").replace("D", "e"))
    if text.lower() in ("nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "-infinity"):
        return float(text)       # parsed so that the range check can name it
    if _WORD_RE.match(text):
        return text              # an unquoted word (some tools write TYRESIDE = LEFT)
    return None


def _fail_line(source: str, lineno: int, line: str, why: str):
    raise ConfigError(f"{source}: line {lineno}: {why}: {line.strip()!r}")


def _read(text: str, source: str):
    """Sections {name: {key: (value, lineno)}} in file order, and tables {section: (header, rows)}."""
    sections: dict[str, dict[str, tuple[object, int]]] = {}
    tables: dict[str, tuple[str, list[tuple[float, ...]]]] = {}
    current: str | None = None
    in_table = False
    for lineno, raw in enumerate(text.splitlines(), start=1):
        body = _strip_comment(raw)
        if body is None:
            _fail_line(source, lineno, raw, "unterminated quoted string")
        body = body.strip()
        if not body:
            continue
        m = _SECTION_RE.match(body)
        if m:
            current = m.group(1).upper()
            if current in sections:
                _fail_line(source, lineno, raw, f"section [{current}] appears twice")
            sections[current] = {}
            in_table = False
            continue
        if body.startswith("["):
            _fail_line(source, lineno, raw, "malformed section header (expected [NAME])")
        if current is None:
            _fail_line(source, lineno, raw, "entry before the first [SECTION] header")
        if body.startswith("{"):
            if not body.endswith("}"):
                _fail_line(source, lineno, raw, "malformed table header (expected {names})")
            tables[current] = (body, [])
            in_table = True
            continue
        if "=" in body:
            key, _, val = body.partition("=")
            key, val = key.strip(), val.strip()
            if not _KEY_RE.match(key):
                _fail_line(source, lineno, raw, f"malformed key {key!r}")
            value = _value(val)
            if value is None or val == "":
                _fail_line(source, lineno, raw, f"malformed value for {key.upper()} "
                                                "(expected a number or a quoted string)")
            key = key.upper()
            if key in sections[current]:
                first = sections[current][key][1]
                _fail_line(source, lineno, raw, f"{key} appears twice in [{current}] (first at line {first})")
            sections[current][key] = (value, lineno)
            in_table = False
            continue
        if in_table:
            try:
                row = tuple(float(t.replace("d", "e").replace("D", "e")) for t in body.split())
            except ValueError:
                _fail_line(source, lineno, raw, "malformed table row (expected numbers)")
            tables[current][1].append(row)
            continue
        _fail_line(source, lineno, raw, "malformed line (expected [SECTION], KEY = value, a $ or ! comment "
                                        "or a table row)")
    return sections, tables


def _lookup(sections, key: str, expected: str):
    """(value, section, lineno) of `key`: its expected section first, else the only other section."""
    if expected in sections and key in sections[expected]:
        v, ln = sections[expected][key]
        return v, expected, ln
    found = [(s, entries[key]) for s, entries in sections.items() if key in entries]
    if len(found) == 1:
        s, (v, ln) = found[0]
        return v, s, ln
    return None, None, None


def parse_tir(text: str, source: str = "<string>") -> TyreProperties:
    """Parse the text of a .tir file. `source` names it in error messages."""
    sections, tables = _read(text, source)

    units = sections.get("UNITS", {})
    for ukey, allowed in SI_UNITS.items():
        if ukey in units:
            v, ln = units[ukey]
            if str(v).strip().lower() not in allowed:
                raise ConfigError(f"{source}: line {ln}: [UNITS] {ukey} = {v!r} not supported "
                                  f"(allowed: {', '.join(repr(a) for a in allowed)}; SI units only)")

    coef: dict[str, float] = {}
    defaulted: list[str] = []
    used: set[tuple[str, str]] = set()
    for key, spec in SCHEMA.items():
        v, sec, ln = _lookup(sections, key, spec.section)
        if v is None:
            if spec.default is REQUIRED:
                raise ConfigError(f"{source}: [{spec.section}] {key}: required key missing")
            coef[key] = float(spec.default)
            defaulted.append(key)
            continue
        used.add((sec, key))
        if isinstance(v, str):
            raise ConfigError(f"{source}: line {ln}: [{sec}] {key} = {v!r}: expected a number")
        v = float(v)
        if not spec.ok(v):
            note = f"; {spec.note}" if spec.note else ""
            raise ConfigError(f"{source}: line {ln}: [{sec}] {key} = {v!r} out of range "
                              f"(allowed: {spec.allowed()}{note})")
        coef[key] = v

    def bad(key, why):
        _, sec, ln = _lookup(sections, key, SCHEMA[key].section)
        where = f"line {ln}: [{sec}] " if ln else f"[{SCHEMA[key].section}] "
        raise ConfigError(f"{source}: {where}{key} = {coef[key]!r} {why}")

    fittyp = coef["FITTYP"]
    if fittyp not in FITTYPS:
        bad("FITTYP", f"not supported (allowed: {', '.join(map(str, FITTYPS))})")
    if coef["PDY1"] == 0.0:
        bad("PDY1", "out of range (allowed: nonzero, |PDY1| <= 10; peak lateral friction coefficient)")
    if coef["RIM_RADIUS"] >= coef["UNLOADED_RADIUS"]:
        bad("RIM_RADIUS", f"out of range (allowed: [0, UNLOADED_RADIUS = {coef['UNLOADED_RADIUS']:g}))")
    if coef["PTY1"] > 0.0 and coef["PTY2"] <= 0.0:
        bad("PTY2", "out of range (allowed: (0, 100] when PTY1 > 0)")
    if coef["QDZ1"] != 0.0 and coef["QCZ1"] <= 0.0:
        bad("QCZ1", "out of range (allowed: (0, 10] when QDZ1 != 0; trail shape factor)")
    if coef["FNOMIN"] / coef["VERTICAL_STIFFNESS"] >= coef["UNLOADED_RADIUS"]:
        bad("VERTICAL_STIFFNESS", "out of range: the deflection at FNOMIN exceeds the unloaded radius")

    tyreside = "LEFT"
    v, sec, _ = _lookup(sections, "TYRESIDE", MODEL)
    if v is not None:
        used.add((sec, "TYRESIDE"))
        tyreside = str(v).upper()

    ignored = tuple(f"{s}.{k}" for s, entries in sections.items() for k in entries
                    if (s, k) not in used and s not in ("UNITS", "MDI_HEADER"))
    params = pack(coef)
    params.setflags(write=False)
    raw = MappingProxyType({s: MappingProxyType({k: v for k, (v, _) in e.items()}) for s, e in sections.items()})
    tabs = MappingProxyType({s: (h, tuple(rows)) for s, (h, rows) in tables.items()})
    return TyreProperties(
        source=source, fittyp=int(fittyp), tyreside=tyreside,
        unloaded_radius=coef["UNLOADED_RADIUS"], width=coef["WIDTH"], aspect_ratio=coef["ASPECT_RATIO"],
        rim_radius=coef["RIM_RADIUS"], rim_width=coef["RIM_WIDTH"], fnomin=coef["FNOMIN"],
        vertical_stiffness=coef["VERTICAL_STIFFNESS"], vertical_damping=coef["VERTICAL_DAMPING"],
        longvl=coef["LONGVL"], vxlow=coef["VXLOW"], coefficients=MappingProxyType(dict(coef)),
        params=params, defaulted=tuple(defaulted), ignored=ignored, sections=raw, tables=tabs)


def load_tir(path: str | Path) -> TyreProperties:
    """Read and parse a .tir file (ConfigError if it is missing, unreadable or invalid). The file is read
    at each call; a text parsed before gives the same (immutable) properties again without parsing."""
    path = Path(path)
    note_read(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except UnicodeDecodeError:
        text = path.read_text(encoding="latin-1")     # old MF-Tool files carry latin-1 comments
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    return _parsed(text, str(path))


@functools.lru_cache(maxsize=16)
def _parsed(text: str, source: str) -> TyreProperties:
    return parse_tir(text, source)


# ---- packing --------------------------------------------------------------------------------------
def pack(coef: Mapping[str, float]) -> np.ndarray:
    """The packed float64 array of the kernels from a complete {KEY: value} mapping (SCHEMA keys),
    with the derived P_LIN_* slots filled in."""
    p = np.zeros(N_PARAMS)
    for i, name in enumerate(PARAM_NAMES):
        if not name.startswith("LIN_"):
            p[i] = float(coef[name])
    # no effective-rolling-radius fit given: Re = R0 - rho/3 (rho = Fz/Cz), the classic estimate
    if p[P_BREFF] == 0.0 and p[P_DREFF] == 0.0 and p[P_FREFF] == 0.0:
        p[P_FREFF] = 1.0 / 3.0
    fz0 = p[P_FNOMIN] * p[P_LFZO]
    # linearised model at Fz = FNOMIN (dfz = 0 when LFZO = 1), gamma = 0
    fz = p[P_FNOMIN]
    dfz = (fz - fz0) / fz0
    p[P_LIN_CX] = fz * (p[P_PKX1] + p[P_PKX2] * dfz) * math.exp(p[P_PKX3] * dfz) * p[P_LKX]
    p[P_LIN_CALPHA] = -p[P_PKY1] * fz0 * math.sin(2.0 * math.atan(fz / (p[P_PKY2] * fz0))) * p[P_LKY]
    p[P_LIN_MUX] = abs(p[P_PDX1] + p[P_PDX2] * dfz) * p[P_LMUX]
    p[P_LIN_MUY] = abs(p[P_PDY1] + p[P_PDY2] * dfz) * p[P_LMUY]
    dt = fz * (p[P_QDZ1] + p[P_QDZ2] * dfz) * (p[P_UNLOADED_RADIUS] / fz0) * p[P_LTR]
    bt = (p[P_QBZ1] + p[P_QBZ2] * dfz + p[P_QBZ3] * dfz * dfz) * p[P_LKY] / p[P_LMUY]
    ct = p[P_QCZ1]
    at = p[P_QHZ1] + p[P_QHZ2] * dfz                       # alpha_t at zero slip
    et = min((p[P_QEZ1] + p[P_QEZ2] * dfz + p[P_QEZ3] * dfz * dfz)
             * (1.0 + p[P_QEZ4] * (2.0 / math.pi) * math.atan(bt * ct * at)), 1.0)
    x = bt * at
    p[P_LIN_TRAIL] = dt * math.cos(ct * math.atan(x - et * (x - math.atan(x))))
    return p


# ---- writing --------------------------------------------------------------------------------------
def _fmt(v) -> str:
    if isinstance(v, str):
        return f"'{v}'"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def format_tir(props: TyreProperties) -> str:
    """The property file text of `props` (every section and key as read, tables included); parsing
    it gives the same coefficients and parameter array."""
    lines = ["$ written by rtsim.vehicle.kit.tyre.tir.format_tir", f"$ from {props.source}"]
    for sec, entries in props.sections.items():
        lines.append(f"[{sec}]")
        for k, v in entries.items():
            lines.append(f"{k:<25s} = {_fmt(v)}")
        if sec in props.tables:
            header, rows = props.tables[sec]
            lines.append(header)
            lines.extend("  ".join(repr(x) for x in row) for row in rows)
    return "\n".join(lines) + "\n"
