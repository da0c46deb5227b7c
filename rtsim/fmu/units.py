"""The channel dictionary's units (rtsim.channels.SI_UNITS) as FMI units: each one's exponents of the SI
base units and its factor (value in base units = factor * value), the way an FMI modelDescription's
<BaseUnit> declares a unit. Two units convert into each other when their exponents agree; the factor
and offset then give the linear map."""
from __future__ import annotations

BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


def _u(factor: float = 1.0, **exp: int) -> tuple[float, dict[str, int]]:
    return factor, exp


#: unit name -> (factor to the base units, {base unit: exponent})
SI: dict[str, tuple[float, dict[str, int]]] = {
    "1": _u(),
    "s": _u(s=1), "ms": _u(1e-3, s=1),
    "m": _u(m=1), "m/s": _u(m=1, s=-1), "m/s^2": _u(m=1, s=-2),
    "rad": _u(rad=1), "rad/s": _u(rad=1, s=-1), "rad/s^2": _u(rad=1, s=-2),
    "N": _u(kg=1, m=1, s=-2), "N*m": _u(kg=1, m=2, s=-2), "J": _u(kg=1, m=2, s=-2),
    "Pa": _u(kg=1, m=-1, s=-2), "kPa": _u(1e3, kg=1, m=-1, s=-2),
    "kg": _u(kg=1), "K": _u(K=1), "A": _u(A=1),
    "V": _u(kg=1, m=2, s=-3, A=-1), "W": _u(kg=1, m=2, s=-3),
}


def exponents(exp: dict[str, int]) -> tuple[int, ...]:
    return tuple(int(exp.get(b, 0)) for b in BASE)


def fmu_unit(md, name: str | None):
    """(factor, offset, exponents) of the unit `name` declared in an fmpy ModelDescription; None when the
    variable has no unit; (None, None, None) when the unit is declared without a <BaseUnit>."""
    if not name:
        return None
    for u in md.unitDefinitions:
        if u.name == name:
            b = u.baseUnit
            if b is None:
                return None, None, None
            return float(b.factor), float(b.offset), exponents({k: getattr(b, k) for k in BASE})
    return None, None, None


def conversion(channel_unit: str, md, fmu_unit_name: str | None) -> tuple[float, float] | str:
    """(a, b) with fmu_value = a * channel_value + b (the channel in its SI unit, the FMU variable in its
    declared unit), or the reason they do not convert. A variable without a unit takes the channel's
    value as it is; a unit named like the channel's converts as the identity even without a BaseUnit."""
    if not fmu_unit_name or fmu_unit_name == channel_unit:
        return 1.0, 0.0
    factor, offset, exp = fmu_unit(md, fmu_unit_name)
    if exp is None:
        return f"the FMU's unit {fmu_unit_name!r} declares no BaseUnit, so it cannot be converted from {channel_unit}"
    cf, cexp = SI[channel_unit]
    if exponents(cexp) != exp:
        return f"unit mismatch: the FMU's {fmu_unit_name!r} is not a unit of the channel's {channel_unit}"
    return cf / factor, -offset / factor
