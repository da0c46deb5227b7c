"""The layer rules of rtsim, bridge and drivers: a module imports from its own layer or a lower one, never
a higher one. Imports inside functions count (a lazy import is still a dependence of the design).

Layers, lowest first (the README's map):

    base      rtsim (package), rtsim.errors, .configfile, .channels, .jit, .boundcall, .compile_status
    mbs       rtsim.mbs, rtsim.model_fault (the formulation and its typed failures)
    road      rtsim.road
    vehicle   rtsim.vehicle (the kit, the assemblies, the registry)
    drivers   drivers (profiles, followers, riders, scenarios: they read the vehicle, not the reverse)
    analysis  rtsim.analyses, rtsim.realtime, rtsim.validate
    bridge    bridge (CAN, Zenoh, MCAP: the outside world)
    apps      rtsim.service, rtsim.batch, rtsim.viewer, rtsim.robustness, rtsim.benchmarks, rtsim.watch,
              rtsim.cli, the validate command (rtsim.validate.cli: it wires the workflow to the bridge's
              MCAP reader and the batch's Ray executor), and the demo ECU processes of drivers
              (drivers.ecu_demo, .eps_demo, .rider_assist_demo, .bus_controller: programs on the far side
              of the bus), the ECU test catalogues (rtsim.ecutest: they run services and ECUs), the vehicle
              as an FMU (rtsim.fmu.export and its slave)

``KNOWN`` lists the wrong-way imports the tree still has, each with its reason; it may only shrink: a
new wrong-way import fails, and so does an entry that no longer occurs (remove it)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rtsim", "bridge", "drivers")

LAYERS = (
    ("base", ("rtsim", "rtsim.errors", "rtsim.configfile", "rtsim.channels", "rtsim.jit", "rtsim.boundcall",
              "rtsim.compile_status")),
    ("mbs", ("rtsim.mbs", "rtsim.model_fault")),
    ("road", ("rtsim.road",)),
    ("vehicle", ("rtsim.vehicle",)),
    ("drivers", ("drivers",)),
    ("analysis", ("rtsim.analyses", "rtsim.realtime", "rtsim.validate")),
    ("bridge", ("bridge",)),
    ("apps", ("rtsim.service", "rtsim.batch", "rtsim.viewer", "rtsim.robustness", "rtsim.benchmarks", "rtsim.watch",
              "rtsim.cli", "rtsim.validate.cli", "drivers.ecu_demo", "drivers.eps_demo", "drivers.rider_assist_demo",
              "drivers.bus_controller", "rtsim.fmu.export", "rtsim.fmu.served_vehicle", "rtsim.fmu.vehicle_step",
              "rtsim.fmu.vehicle_slave", "rtsim.ecutest")),
)

#: (importer, imported) -> why it is still there. Shrink it; never grow it.
KNOWN = {
}


def layer_of(module: str) -> int | None:
    """Index in LAYERS of the longest prefix naming the module (None: not one of ours)."""
    best = None
    for i, (_name, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and (best is None or len(p) > best[1]):
                best = (i, len(p))
    return None if best is None else best[0]


def _sources(root: Path) -> dict[str, str]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            if "node_modules" in path.parts:
                continue
            parts = path.relative_to(root).with_suffix("").parts
            is_pkg = parts[-1] == "__init__"
            out[".".join(parts[:-1] if is_pkg else parts) + (".__init__" if is_pkg else "")] = path.read_text()
    return out


def imports(name: str, source: str) -> set[str]:
    """The modules a module's import statements name, at any depth (relative ones made absolute)."""
    is_pkg = name.endswith(".__init__")
    mod = name[:-len(".__init__")] if is_pkg else name
    here = mod if is_pkg else mod.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join(pkg + ([base] if base else []))
            found.add(base)
    return found


def wrong_way(sources: dict[str, str]) -> set[tuple[str, str]]:
    """(importer, imported) pairs where a module imports from a higher layer."""
    bad = set()
    for name, src in sources.items():
        mod = name[:-len(".__init__")] if name.endswith(".__init__") else name
        mine = layer_of(mod)
        for target in imports(name, src):
            theirs = layer_of(target)
            if mine is not None and theirs is not None and theirs > mine:
                bad.add((mod, target))
    return bad


def test_layers_hold_but_for_the_known_violations():
    found = wrong_way(_sources(ROOT))
    new = sorted(found - set(KNOWN))
    assert not new, "wrong-way imports (a module imports a higher layer): " + "; ".join(f"{a} -> {b}" for a, b in new)
    fixed = sorted(set(KNOWN) - found)
    assert not fixed, "no longer occurs, remove from KNOWN: " + "; ".join(f"{a} -> {b}" for a, b in fixed)


def test_a_planted_wrong_way_import_fails_the_check():
    sources = _sources(ROOT)
    assert not (wrong_way(sources) - set(KNOWN))
    planted = dict(sources)
    planted["rtsim.mbs.planted"] = "def f():\n    from bridge.can_bus import open_bus\n    return open_bus\n"
    planted["rtsim.vehicle.car.planted"] = "from ...service import loop\n"
    planted["drivers.planted"] = "import rtsim.viewer.server\n"
    # the rules of the vehicle interface: the vehicle never imports its drivers or riders, the core never
    # the bridge
    planted["rtsim.vehicle.motorcycle.planted"] = "from drivers.rider import rider_step\n"
    planted["rtsim.analyses.planted"] = ("def read(p):\n    from bridge.mcap_log import read_run\n"
                                         "    return read_run(p)\n")
    found = wrong_way(planted) - set(KNOWN)
    assert found == {("rtsim.mbs.planted", "bridge.can_bus"), ("rtsim.vehicle.car.planted", "rtsim.service"),
                     ("drivers.planted", "rtsim.viewer.server"), ("rtsim.vehicle.motorcycle.planted", "drivers.rider"),
                     ("rtsim.analyses.planted", "bridge.mcap_log")}


def test_the_rules_read_as_stated():
    order = [n for n, _ in LAYERS]
    assert order.index("mbs") < order.index("vehicle") < order.index("drivers") < order.index("bridge") \
        < order.index("apps")
    assert layer_of("rtsim.service.loop") == order.index("apps")
    assert layer_of("drivers.rider") == order.index("drivers")
    assert layer_of("drivers.ecu_demo") == order.index("apps")
    assert layer_of("rtsim.validate.cli") == order.index("apps")
    assert layer_of("rtsim.validate.workflow") == order.index("analysis")
    assert layer_of("numpy") is None
