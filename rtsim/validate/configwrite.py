"""Adding the identified effects to the model: a new vehicle config written next to the report (the
original file is never touched), shown as a unified diff.

The new file is the original text, with relative file references (e.g. `property_file`) rewritten so
they still point at the same files from the new location (relative when both share a folder below
the root, absolute otherwise), and the identified effects appended as
`[effects.<name>]` tables (sensor effects as `[[effects.<name>]]` arrays of tables with `channel`),
each value with its 95 % half-width in a comment. The result is opened back as a vehicle file
(rtsim.vehicle.registry.open_vehicle: its kind's loader), so a file the model would reject is never left
behind as if it were valid.
"""
from __future__ import annotations

import difflib
import os
import re
import tomllib
from pathlib import Path

from rtsim.errors import ConfigError
from rtsim.vehicle.registry import open_vehicle

from .effectset import Effect

_STRING = re.compile(r'^(\s*[A-Za-z0-9_]+\s*=\s*)"([^"]*)"(.*)$')


def toml_number(x: float) -> str:
    s = f"{float(x):.6g}"
    if s in ("inf", "-inf", "nan"):
        raise ConfigError(f"cannot write the value {x} to a vehicle config")
    return s if any(ch in s for ch in ".en") else s + ".0"


def _rebase(text: str, src_dir: Path, dst_dir: Path) -> str:
    """Relative paths in string values that name existing files, rewritten relative to dst_dir."""
    out = []
    for line in text.splitlines(keepends=True):
        m = _STRING.match(line.rstrip("\n"))
        if m and m.group(2) and not os.path.isabs(m.group(2)) and (src_dir / m.group(2)).is_file():
            target, here = (src_dir / m.group(2)).resolve(), dst_dir.resolve()
            common = Path(os.path.commonpath([target, here]))
            new = os.path.relpath(target, here) if common != Path(common.anchor) else str(target)
            line = f'{m.group(1)}"{Path(new).as_posix()}"{m.group(3)}' + ("\n" if line.endswith("\n") else "")
        out.append(line)
    return "".join(out)


def effects_toml(effects: list[Effect], header: str) -> str:
    lines = ["", f"# ---- {header}"]
    for e in effects:
        unc = e.uncertainty
        if e.kind == "sensor":
            lines.append(f"[[effects.{e.name}]]")
            lines.append(f'channel = "{e.channel}"')
        else:
            lines.append(f"[effects.{e.name}]")
        for k, v in e.values().items():
            u = unc.get(k)
            note = f"   # +- {u:.2g} (95 %)" if u is not None and u == u and abs(u) != float("inf") else ""
            lines.append(f"{k} = {toml_number(v)}{note}")
        lines.append("")
    return "\n".join(lines)


def write_config(original: str | Path, effects: list[Effect], out: str | Path, header: str) -> str:
    """Write the new config to `out`; return the unified diff from the original."""
    original, out = Path(original), Path(out)
    text = original.read_text()
    try:
        existing = tomllib.loads(text).get("effects")
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{original}: not valid TOML ({exc})") from None
    if existing is not None and not isinstance(existing, dict):
        raise ConfigError(f"{original}: 'effects' is not a table; cannot add effects to it")
    new = _rebase(text, original.parent, out.parent)
    if not new.endswith("\n"):
        new += "\n"
    new += effects_toml(effects, header)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(new)
    try:
        open_vehicle(out)
    except ConfigError as exc:
        bad = out.with_suffix(".rejected.toml")
        out.replace(bad)
        raise ConfigError(f"the vehicle config with the identified effects does not load ({exc}); kept as {bad}") \
            from None
    return "".join(difflib.unified_diff(text.splitlines(keepends=True), new.splitlines(keepends=True),
                                        fromfile=str(original), tofile=str(out)))
