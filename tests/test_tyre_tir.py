"""The .tir parser: the shipped 155/80 R13 file, round trip, defaults, and every kind of bad file
(ConfigError naming file + section + key, file + line, or key + value + allowed range)."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.vehicle.kit.tyre import tir
from rtsim.vehicle.kit.tyre.tir import (N_PARAMS, PARAM_NAMES, P_FNOMIN, P_LIN_CALPHA, P_LIN_CX, P_PDX1, P_PKY1,
                                    P_UNLOADED_RADIUS, SCHEMA, format_tir, load_tir, parse_tir)

SHIPPED = Path(__file__).resolve().parents[1] / "configs" / "tyres" / "michelin_155_80_r13.tir"

MINIMAL = """\
[UNITS]
LENGTH = 'meter'
[MODEL]
FITTYP = 6
[DIMENSION]
UNLOADED_RADIUS = 0.3
[VERTICAL]
FNOMIN = 3000
VERTICAL_STIFFNESS = 200000
[LONGITUDINAL_COEFFICIENTS]
PCX1 = 1.6
PDX1 = 1.1
PKX1 = 20
[LATERAL_COEFFICIENTS]
PCY1 = 1.3
PDY1 = 0.9
PKY1 = -15
PKY2 = 1.7
"""


def write(tmp_path: Path, text: str, name: str = "t.tir") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def replace_line(text: str, key: str, new: str | None) -> str:
    """`text` with the line defining `key` replaced by `new` (removed when None)."""
    out, hit = [], False
    for line in text.splitlines():
        if re.match(rf"^\s*{key}\s*=", line):
            hit = True
            if new is not None:
                out.append(new)
        else:
            out.append(line)
    assert hit, key
    return "\n".join(out) + "\n"


def line_of(text: str, key: str) -> int:
    for i, line in enumerate(text.splitlines(), start=1):
        if re.match(rf"^\s*{key}\s*=", line):
            return i
    raise AssertionError(key)


# ---- the index constants --------------------------------------------------------------------------
def test_index_constants_are_one_contiguous_table():
    assert len(PARAM_NAMES) == N_PARAMS == len(set(PARAM_NAMES))
    for i, name in enumerate(PARAM_NAMES):
        assert getattr(tir, "P_" + name) == i
    assert P_PDX1 == PARAM_NAMES.index("PDX1")


# ---- the shipped file -----------------------------------------------------------------------------
def test_shipped_file_is_a_plausible_155_80_r13():
    t = load_tir(SHIPPED)
    assert t.fittyp == 6 and t.tyreside == "LEFT"
    assert 0.285 <= t.unloaded_radius <= 0.292 and t.width == pytest.approx(0.155)
    assert t.rim_radius == pytest.approx(13 * 0.0254 / 2, abs=1e-4)
    assert 2500 <= t.fnomin <= 3000
    assert 150e3 <= t.vertical_stiffness <= 180e3
    p = t.params
    assert p.shape == (N_PARAMS,) and p.dtype == np.float64 and not p.flags.writeable
    assert 35e3 <= p[P_LIN_CALPHA] <= 45e3           # cornering stiffness at FNOMIN
    assert 50e3 <= p[P_LIN_CX] <= 70e3               # longitudinal slip stiffness at FNOMIN
    assert 0.9 <= t["PDX1"] <= 1.1 and 0.85 <= abs(t["PDY1"]) <= 1.1
    assert p[P_PKY1] == t["PKY1"] < 0                # ISO sign convention
    # everything the subset reads is in the file; the rest is kept and listed
    assert t.defaulted == ()
    assert t.ignored == ("MODEL.PROPERTY_FILE_FORMAT",)
    assert t.tables["SHAPE"][0] == "{radial width}" and len(t.tables["SHAPE"][1]) == 4
    assert "NOT A MEASURED FIT" in SHIPPED.read_text()


def test_round_trip_gives_the_same_parameters(tmp_path):
    t = load_tir(SHIPPED)
    text = format_tir(t)
    t2 = load_tir(write(tmp_path, text))
    np.testing.assert_array_equal(t2.params, t.params)
    assert dict(t2.coefficients) == dict(t.coefficients)
    assert {s: dict(e) for s, e in t2.sections.items()} == {s: dict(e) for s, e in t.sections.items()}
    assert t2.tables == t.tables
    assert format_tir(t2).splitlines()[2:] == text.splitlines()[2:]   # a fixed point after one pass


# ---- syntax ---------------------------------------------------------------------------------------
def test_comments_quotes_case_and_fortran_exponents():
    text = MINIMAL.replace("[MODEL]", "[model]   $ lower-case section, trailing comment") + """\
! a comment line
$ another one
[ROLLING_COEFFICIENTS]
qsy1 = 1.2D-2     ! lower-case key, Fortran exponent, ! comment
[MDI_HEADER]
COMMENT = 'a $dollar and !bang inside quotes'
TYRESIDE2 = "double quotes"
"""
    t = parse_tir(text, "mem.tir")
    assert t["QSY1"] == pytest.approx(0.012)
    assert t.sections["MDI_HEADER"]["COMMENT"] == "a $dollar and !bang inside quotes"
    assert t.sections["MDI_HEADER"]["TYRESIDE2"] == "double quotes"


def test_missing_optional_keys_take_the_mf_defaults():
    t = parse_tir(MINIMAL, "min.tir")
    for key in ("PDX2", "PEX1", "PHX1", "PVY1", "RBX1", "QSY1", "QDZ1", "PTX1"):
        assert t[key] == 0.0 and key in t.defaulted
    for key in ("LFZO", "LMUX", "LMUY", "LKX", "LKY", "LTR", "LMY", "LXAL", "LYKA"):
        assert t[key] == 1.0 and key in t.defaulted
    assert t.vxlow == 1.0 and t.longvl == pytest.approx(16.7)
    # no BREFF/DREFF/FREFF: Re = R0 - rho/3
    from rtsim.vehicle.kit.tyre import effective_rolling_radius
    assert effective_rolling_radius(t.params, 3000.0) == pytest.approx(0.3 - 3000 / 200000 / 3)


def test_key_in_an_unexpected_section_is_accepted():
    text = MINIMAL.replace("PKX1 = 20\n", "").replace("PKY2 = 1.7\n", "PKY2 = 1.7\nPKX1 = 20\n")
    assert parse_tir(text, "x.tir")["PKX1"] == 20.0


# ---- errors ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, section", [("FNOMIN", "VERTICAL"), ("UNLOADED_RADIUS", "DIMENSION"),
                                          ("PDX1", "LONGITUDINAL_COEFFICIENTS"),
                                          ("PKY1", "LATERAL_COEFFICIENTS")])
def test_missing_required_key_names_file_section_and_key(tmp_path, key, section):
    path = write(tmp_path, replace_line(SHIPPED.read_text(), key, None), "missing.tir")
    with pytest.raises(ConfigError) as exc:
        load_tir(path)
    msg = str(exc.value)
    assert str(path) in msg and f"[{section}]" in msg and key in msg and "missing" in msg


@pytest.mark.parametrize("bad", ["PDX1 1.0", "PDX1 = 1.0.3", "PDX1 = ", "[LATERAL", "= 3",
                                 "COMMENT = 'unterminated", "PDX1 = 1 2"])
def test_malformed_line_names_file_and_line(tmp_path, bad):
    text = SHIPPED.read_text()
    lineno = line_of(text, "PDX1")
    path = write(tmp_path, replace_line(text, "PDX1", bad), "malformed.tir")
    with pytest.raises(ConfigError) as exc:
        load_tir(path)
    msg = str(exc.value)
    assert str(path) in msg and f"line {lineno}" in msg


def test_duplicate_key_names_both_lines(tmp_path):
    text = SHIPPED.read_text()
    first = line_of(text, "PKX1")
    text = text.replace("PKX2 ", "PKX1 = 20\nPKX2 ", 1)
    with pytest.raises(ConfigError, match=rf"line {first + 1}: PKX1 appears twice .*first at line {first}"):
        parse_tir(text, "dup.tir")


@pytest.mark.parametrize("key, value, allowed", [
    ("UNLOADED_RADIUS", "-0.3", "(0, 2]"),
    ("FNOMIN", "0", "(0, 1e+06]"),
    ("FNOMIN", "-2800", "(0, 1e+06]"),
    ("VERTICAL_STIFFNESS", "nan", "(0, 1e+09]"),
    ("PDX1", "inf", "(0, 10]"),
    ("PKY1", "15.6", "[-1000, 0)"),
    ("LMUY", "0", "(0, 100]"),
    ("QSY1", "-0.01", "[0, 1]"),
])
def test_out_of_range_value_names_key_value_and_range(tmp_path, key, value, allowed):
    path = write(tmp_path, replace_line(SHIPPED.read_text(), key, f"{key} = {value}"), "range.tir")
    with pytest.raises(ConfigError) as exc:
        load_tir(path)
    msg = str(exc.value)
    assert str(path) in msg and key in msg and "out of range" in msg and allowed in msg
    assert repr(float(value)) in msg


def test_cross_checks_and_enumerations():
    with pytest.raises(ConfigError, match=r"FITTYP = 7.0 not supported \(allowed: 5, 6, 21, 52, 61, 62\)"):
        parse_tir(MINIMAL.replace("FITTYP = 6", "FITTYP = 7"), "f.tir")
    with pytest.raises(ConfigError, match=r"RIM_RADIUS = 0.35 out of range"):
        parse_tir(MINIMAL.replace("UNLOADED_RADIUS = 0.3", "UNLOADED_RADIUS = 0.3\nRIM_RADIUS = 0.35"), "r.tir")
    with pytest.raises(ConfigError, match=r"\[UNITS\] LENGTH = 'mm' not supported"):
        parse_tir(MINIMAL.replace("'meter'", "'mm'"), "u.tir")
    with pytest.raises(ConfigError, match=r"PDX1 = 'abc': expected a number"):
        parse_tir(MINIMAL.replace("PDX1 = 1.1", "PDX1 = abc"), "s.tir")
    with pytest.raises(ConfigError, match=r"PDY1 = 0.0 out of range"):
        parse_tir(MINIMAL.replace("PDY1 = 0.9", "PDY1 = 0"), "d.tir")
    with pytest.raises(ConfigError, match=r"line 1: entry before the first \[SECTION\]"):
        parse_tir("FNOMIN = 1\n" + MINIMAL, "e.tir")


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_tir(tmp_path / "nope.tir")


def test_every_schema_range_is_stated():
    for key, spec in SCHEMA.items():
        allowed = spec.allowed()
        assert allowed[0] in "([" and allowed[-1] in ")]", key
        if spec.default is not tir.REQUIRED and key != "FITTYP":
            assert spec.ok(float(spec.default)), key        # defaults are inside their ranges
    assert math.isfinite(load_tir(SHIPPED).params[P_FNOMIN] + load_tir(SHIPPED).params[P_UNLOADED_RADIUS])
