"""What `rtsim validate` knows of a vehicle comes from the vehicle (rtsim.vehicle.validation): every shipped
vehicle file opens to a validation profile whose replayer, catalogue and channels the workflow can use, and
rtsim/validate holds no branch on the vehicle's kind (a comparison with a kind's name fails this test, as a
planted one shows)."""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

from rtsim.validate.effectset import SENSOR_EFFECTS, kind
from rtsim.validate.workflow import make_replayer
from rtsim.vehicle.registry import KINDS, VEHICLES, open_vehicle

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(VEHICLES.glob("*.toml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_vehicle_provides_a_validation_profile(path):
    """The profile names an importable replayer class, inputs that are not compared, the vehicle's own sensor
    channels (its channel dictionary's), and a catalogue whose sensor effects are exactly those of the one
    sensor model (the effect's kind is read from its name: rtsim.validate.effectset.kind)."""
    import importlib

    opened = open_vehicle(path)
    prof = opened.validation
    module, _, name = prof.replayer.partition(":")
    assert inspect.isclass(getattr(importlib.import_module(module), name))
    assert prof.inputs and not set(prof.inputs) & set(prof.compared or ())
    assert set(prof.min_range) <= set(prof.inputs)
    assert prof.sensor_names and set(prof.compared or ()) <= set(prof.sensor_names)
    assert {n for n, e in prof.effects.items() if e.kind == "sensor"} == set(SENSOR_EFFECTS)
    assert all(kind(n) == e.kind for n, e in prof.effects.items())
    assert "{compared}" in prof.manoeuvre or not prof.manoeuvre


def test_the_profile_builds_its_replayer():
    """The workflow builds the replayer the profile names, on the vehicle file, and the replayer carries the
    same profile (the fits read the catalogue from it)."""
    vehicle = VEHICLES / "motorcycle.toml"
    prof = open_vehicle(vehicle).validation
    rp = make_replayer(prof, vehicle, None, 1e-3, 2e-3)
    assert rp.profile == prof
    assert tuple(rp.sensor_names) == prof.sensor_names


def kind_branches(source: str, name: str) -> list[str]:
    """Comparisons with a vehicle kind's name (rtsim.vehicle.registry.KINDS): `x == "two_wheeler"`,
    `"car" != y`, `k in ("car", ...)`, as "file:line" strings."""
    out = []
    for node in ast.walk(ast.parse(source, name)):
        if not isinstance(node, ast.Compare):
            continue
        for side in (node.left, *node.comparators):
            consts = [side] if isinstance(side, ast.Constant) else \
                list(side.elts) if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else []
            if any(isinstance(c, ast.Constant) and c.value in KINDS for c in consts):
                out.append(f"{name}:{node.lineno}")
                break
    return out


def test_no_branch_on_the_vehicle_kind_in_validate():
    found = []
    for path in sorted((ROOT / "rtsim" / "validate").rglob("*.py")):
        found += kind_branches(path.read_text(), str(path.relative_to(ROOT)))
    assert not found, "branches on the vehicle kind (put the difference in the vehicle's validation profile): " + \
        ", ".join(found)
    planted = ('def f(rp, kind):\n    if getattr(rp, "kind", "car") == "two_wheeler":\n        return 1\n'
               '    return kind in ("car",)\n')
    assert kind_branches(planted, "planted.py") == ["planted.py:2", "planted.py:4"]
