#!/usr/bin/env python3
"""Regenerate the measured figures of docs/figures.md by running the commands that measure them.

    python tools/docs_figures.py                 every block (a few minutes on a 2-core machine)
    python tools/docs_figures.py --only vehicle  one block (repeatable)
    python tools/docs_figures.py --check         the file's blocks and this script's agree (runs nothing)

docs/figures.md holds one block per entry of ``BLOCKS``, between ``<!-- BEGIN name -->`` and
``<!-- END name -->``. Each block is rewritten whole: the command that measured it, when, on how many CPUs
and under what load, then its table, rendered from the command's JSON output. Text outside the blocks is
left as it is. No figure in the docs is typed by hand: a measured number lives in a block here, or the
page names the command that prints it.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, NamedTuple

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures.md"


class Block(NamedTuple):
    args: tuple[str, ...]                      # rtsim's arguments ("{out}": a temporary JSON file)
    render: Callable[[object], list[str]]      # the command's JSON -> markdown lines


def _num(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def render_mbs(res) -> list[str]:
    """`rtsim bench --json --scaling`: the IFToMM problems and the N-four-bar's cost."""
    lines = ["| problem | step (s) | t_end (s) | us/step | max \\|Φ\\| | max \\|Φ̇\\| | energy drift (J) | "
             "Newton iterations/step |", "|---|---|---|---|---|---|---|---|"]
    for r in res["problems"]:
        lines.append(f"| {r['problem']} | {r['dt']:g} | {r['t_end']:g} | {r['us_per_step']:.1f} | "
                     f"{r['max_position_constraint_violation']:.1e} | {r['max_velocity_constraint_violation']:.1e} | "
                     f"{_num(r['energy_drift'], '.1e')} | {_num(r.get('newton_iterations_per_step'), '.2f')} |")
    lines += ["", "| N-four-bar, N | coordinates | us/step |", "|---|---|---|"]
    lines += [f"| {s['N']} | {s['n_coordinates']} | {s['us_per_step']:.1f} |" for s in res["scaling"]]
    return lines


def render_vehicle(res) -> list[str]:
    """`rtsim bench --suite vehicle --json`: cost per 1 ms step and the share of each part."""
    lines = ["| scenario | us/step | Newton iterations/step | factorisations/step | largest parts (share) |",
             "|---|---|---|---|---|"]
    for r in res:
        parts = sorted(r["share"].items(), key=lambda kv: -kv[1])[:3]
        shares = ", ".join(f"{k.split(' (')[0]} {100 * v:.0f} %" for k, v in parts) or "-"
        lines.append(f"| {r['scenario']} | {r['us_per_step']:.1f} | {r['newton_iterations_per_step']:.2f} | "
                     f"{r['factorizations_per_step']:.1f} | {shares} |")
    return lines


def render_dispatch(res) -> list[str]:
    """`rtsim bench --suite dispatch --json`: a call into a kernel, direct and bound."""
    lines = [f"{res['fixed_tuples']} fixed named tuples, {res['fixed_arrays']} arrays, "
             f"{res['fixed_scalars']} scalars.", "", "| call | us per call, median | best |", "|---|---|---|"]
    lines += [f"| {k} | {v['median']:.2f} | {v['best']:.2f} |" for k, v in res["us_per_call"].items()]
    return lines


def render_fmu(res) -> list[str]:
    """`rtsim bench --suite fmu --json`: one controller FMU call and the car as an FMU, beside the 1 ms budget."""
    b = res["loop_budget_us"]
    rows = (("controller FMU call (set 1 input, doStep, get 2 outputs)", res["controller_call_us"]),
            (f"car FMU doStep of 1 ms (set 3 commands, get {res['vehicle_fmu_outputs']} channels)",
             res["vehicle_fmu_dostep_us"]),
            ("car step in rtsim (1 ms, channels read)", res["vehicle_step_us"]))
    lines = ["| call | us per call, median | best | median share of 1 ms |", "|---|---|---|---|"]
    lines += [f"| {k} | {v['median']:.1f} | {v['best']:.1f} | {100 * v['median'] / b:.1f} % |" for k, v in rows]
    return lines


def render_eigen(res) -> list[str]:
    """`rtsim eigen --vehicle motorcycle --speeds 5:60:5 --out FILE`: where each mode changes stability."""
    lines = ["| mode | becomes | at (m/s) |", "|---|---|---|"]
    for c in res.get("stability_changes", []):
        lines.append(f"| {c['mode']} | {c.get('becomes', c.get('to', '?'))} | {c['speed_m_s']:.2f} |")
    return lines


BLOCKS: dict[str, Block] = {
    "mbs": Block(("bench", "--json", "--scaling"), render_mbs),
    "vehicle": Block(("bench", "--suite", "vehicle", "--json"), render_vehicle),
    "dispatch": Block(("bench", "--suite", "dispatch", "--json"), render_dispatch),
    "fmu": Block(("bench", "--suite", "fmu", "--json"), render_fmu),
    "eigen-motorcycle": Block(("eigen", "--vehicle", "motorcycle", "--speeds", "5:60:5", "--out", "{out}"),
                              render_eigen),
}


def command_line(block: Block) -> str:
    return "rtsim " + " ".join("FILE.json" if a == "{out}" else a for a in block.args)


def run_block(block: Block) -> object:
    """Run the block's command with this interpreter's rtsim; its JSON (stdout, or the --out file)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        args = [str(out) if a == "{out}" else a for a in block.args]
        proc = subprocess.run([sys.executable, "-m", "rtsim.cli", *args], cwd=ROOT, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"docs_figures: {command_line(block)} failed (exit {proc.returncode}):\n"
                             f"{proc.stderr[-2000:]}")
        return json.loads(out.read_text() if "{out}" in block.args else proc.stdout)


def conditions() -> str:
    """When and where: the date, the CPUs and the load average (figures depend on all three)."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    when = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return f"{when}, {os.cpu_count()} CPUs ({platform.machine()}), load average {load:.1f}"


def block_text(name: str, block: Block, result) -> str:
    body = [f"<!-- BEGIN {name}: written by tools/docs_figures.py; edit the script, not this block -->",
            f"Command: `{command_line(block)}` (run {conditions()}).", "", *block.render(result),
            f"<!-- END {name} -->"]
    return "\n".join(body)


def _span(text: str, name: str) -> re.Match | None:
    return re.search(rf"<!-- BEGIN {re.escape(name)}\b.*?<!-- END {re.escape(name)} -->", text, re.S)


def replace_block(text: str, name: str, new: str) -> str:
    """``text`` with block ``name`` replaced by ``new`` (which carries its own markers); an error if the
    file has no such block."""
    m = _span(text, name)
    if m is None:
        raise SystemExit(f"docs_figures: {FIGURES.name} has no block {name!r} (add its BEGIN/END markers)")
    return text[:m.start()] + new + text[m.end():]


def check(text: str) -> list[str]:
    """Disagreements between the file and BLOCKS: a block missing or twice, a block of no command, a block
    that does not name its command."""
    problems = []
    found = re.findall(r"<!-- BEGIN ([\w-]+)", text)
    for name, block in BLOCKS.items():
        n = found.count(name)
        if n != 1:
            problems.append(f"block {name!r} appears {n} times")
            continue
        if f"`{command_line(block)}`" not in _span(text, name).group(0):
            problems.append(f"block {name!r} does not name its command `{command_line(block)}`")
    problems += [f"block {name!r} has no command in tools/docs_figures.py" for name in found if name not in BLOCKS]
    return problems


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python tools/docs_figures.py", description=__doc__.splitlines()[0])
    p.add_argument("--only", action="append", choices=sorted(BLOCKS), metavar="NAME",
                   help=f"regenerate only this block (repeatable): {', '.join(BLOCKS)}")
    p.add_argument("--check", action="store_true", help="check the file against the blocks; run nothing")
    args = p.parse_args(argv)
    text = FIGURES.read_text()
    if args.check:
        problems = check(text)
        for line in problems:
            print(f"docs_figures: {line}", file=sys.stderr)
        return 1 if problems else 0
    for name in args.only or list(BLOCKS):
        block = BLOCKS[name]
        print(f"docs_figures: {command_line(block)} ...", file=sys.stderr, flush=True)
        text = replace_block(text, name, block_text(name, block, run_block(block)))
        FIGURES.write_text(text)                 # after each block: a later failure keeps the earlier ones
    return 0


if __name__ == "__main__":
    sys.exit(main())
