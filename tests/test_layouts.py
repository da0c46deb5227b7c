"""Index layouts are named enumerations, and a bare layout prefix means one thing in the whole tree.

A module-level run of at least three consecutive integer constants 0, 1, 2, ... with the same prefix
(``ST_INIT = 0``, ``ST_T = 1``, ``ST_V = 2``) is an index layout: the slots of one array. Single constants and
shorter runs (``P_RAMP``, ``PURE_PURSUIT``/``STANLEY``) are not. Two modules of rtsim, drivers and bridge that
define a layout with the same prefix name two different arrays with one name; new layouts are IntEnum classes
(``PtIn``, ``SpeedState``) instead. ``KNOWN`` lists the clashes the tree still has, each with its reason; it may
only shrink: a new clash fails, and so does an entry that no longer occurs (remove it)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rtsim", "bridge", "drivers")
MIN_RUN = 3     # consecutive slots 0, 1, 2, ... that make a layout

# prefix -> ((the modules, sorted), reason). Empty: rtsim.mbs.model's ST_ (the integrator's statistics) and
# the TIR tyre's P_ are the only layouts with those prefixes since the followers and the rider use IntEnums.
KNOWN: dict[str, tuple[tuple[str, ...], str]] = {
}


def _int_constants(tree):
    """(name, value) of the module-level assignments NAME = <int literal>, in source order."""
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and isinstance(node.value, ast.Constant) and type(node.value.value) is int):
            yield node.targets[0].id, node.value.value


def layout_prefixes(source: str) -> set[str]:
    """The prefixes (``ST_``) of the index layouts defined at module level in ``source``."""
    found, prefix, expect = set(), None, 0
    for name, value in _int_constants(ast.parse(source)):
        head = name.split("_", 1)[0] + "_" if "_" in name else None
        if head is not None and head == prefix and value == expect:
            expect += 1
        else:
            prefix, expect = (head, 1) if value == 0 else (None, 0)
        if prefix is not None and expect >= MIN_RUN:
            found.add(prefix)
    return found


def layouts(sources: dict[str, str]) -> dict[str, list[str]]:
    """Prefix -> the modules (sorted) that define a layout with it."""
    owners: dict[str, list[str]] = {}
    for module, source in sorted(sources.items()):
        for prefix in layout_prefixes(source):
            owners.setdefault(prefix, []).append(module)
    return owners


def clashes(sources: dict[str, str]) -> dict[str, tuple[str, ...]]:
    return {p: tuple(m) for p, m in layouts(sources).items() if len(m) > 1}


def tree_sources() -> dict[str, str]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            out[module] = path.read_text(encoding="utf-8")
    return out


def test_run_rule():
    assert layout_prefixes("A_X = 0\nA_Y = 1\nA_Z = 2\n") == {"A_"}
    assert layout_prefixes("A_X = 0\nA_Y = 1\n") == set()                 # two slots: not a layout
    assert layout_prefixes("P_RAMP = 0\nP_ROLL = 1\nQ = 2\n") == set()    # scalar constants
    assert layout_prefixes("A_X = 1\nA_Y = 2\nA_Z = 3\n") == set()        # not 0, 1, 2, ...


def test_no_new_prefix_clash():
    found = clashes(tree_sources())
    assert {p: m for p, m in found.items() if KNOWN.get(p, (None,))[0] != m} == {}, "a layout prefix names " \
        "different arrays in different modules: make it an IntEnum (see rtsim.vehicle.kit.powertrain.PtIn)"
    assert set(KNOWN) - set(found) == set(), "a KNOWN clash no longer occurs: remove it"


def test_planted_clash_fails():
    sources = tree_sources()
    sources["drivers.planted"] = "ZZ_A = 0\nZZ_B = 1\nZZ_C = 2\n"
    sources["rtsim.vehicle.planted"] = "ZZ_X = 0\nZZ_Y = 1\nZZ_Z = 2\n"
    assert clashes(sources)["ZZ_"] == ("drivers.planted", "rtsim.vehicle.planted")
