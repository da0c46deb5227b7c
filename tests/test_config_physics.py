"""Vehicle files checked as physics on load (issue 29, item 7): every shipped vehicle passes; a file made
from a shipped one with one key changed to describe an impossible machine is refused with one line naming
the file, the key, the value and the rule, by the one config mechanism (rtsim.configfile), before any
model is built. So no command (run, serve, eigen, statics, inverse; describe for the cars) meets such a file's numbers:
each ends with that line and exit status 2, never a numpy traceback.

The rules: masses and inertias positive where the model needs them (a wheel is a body whose axes are
coordinates), inertia tensors a rigid body's (positive principal moments, triangle inequality); travel
limits ordered around the design position; linkages non-degenerate (pivots and link ends at least 10 mm
apart, ball joints off their arm's axis) and the steering ratio computed from the linkage inside the
plausible band of road cars; a two-wheeler's wheels apart, its centre of mass between the contacts and a
positive trail where tyre forces steer the fork."""
from __future__ import annotations

import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.kit.linkage_checks import STEERING_RATIO_RANGE, steering_ratio
from rtsim.vehicle.kit.linkages import DoubleWishbone, VerticalSlider
from rtsim.vehicle.motorcycle.config import load_motorcycle

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = ROOT / "configs" / "vehicles"
CARS = ("xbw.toml", "xbw_fwd.toml", "eps_car.toml")
TWO_WHEELERS = ("motorcycle.toml", "whipple_benchmark.toml")


def load(path: Path):
    """The loader every command opens a vehicle file with, by its kind."""
    kind = tomllib.loads(path.read_text()).get("kind")
    return (load_motorcycle if kind == "two_wheeler" else load_vehicle)(path)


def toml_value(v) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return repr(float(v))


def with_key(text: str, dotted: str, value) -> str:
    """The file's text with `dotted` (a key's line in its [section], or a new line after the header) set to
    `value`; comments and everything else as they were."""
    section, _, key = dotted.rpartition(".")
    lines = text.splitlines()
    start = 0
    if section:
        start = next(i for i, ln in enumerate(lines) if ln.split("#")[0].strip() == f"[{section}]") + 1
    end = next((i for i in range(start, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    line = f"{key} = {toml_value(value)}"
    for i in range(start, end):
        if re.match(rf"{re.escape(key)}\s*=", lines[i]):
            lines[i] = line
            break
    else:
        lines.insert(start, line)
    return "\n".join(lines) + "\n"


def get(data: dict, dotted: str):
    for k in dotted.split("."):
        data = data[k]
    return data


@pytest.fixture(scope="module")
def vehicles_dir(tmp_path_factory) -> Path:
    """A folder beside links to the shipped tyre and CAN files, so the written vehicle files' relative
    paths (../tyres, ../can) resolve as the shipped ones'."""
    base = tmp_path_factory.mktemp("configs")
    for sub in ("tyres", "can"):
        (base / sub).symlink_to(ROOT / "configs" / sub)
    (base / "vehicles").mkdir()
    return base / "vehicles"


def write_bad(vehicles_dir: Path, shipped: str, dotted: str, value) -> Path:
    text = with_key((VEHICLES / shipped).read_text(), dotted, value)
    path = vehicles_dir / f"{Path(shipped).stem}__{dotted.replace('.', '_')}.toml"
    path.write_text(text)
    assert get(tomllib.loads(text), dotted) == (list(value) if isinstance(value, tuple) else value)
    return path


# (shipped file, key, value, the rule's words in the error line[, the key the line names if not the one changed:
# the steering ratio is the linkage's and the rack's together, and the line names the rack's key)
BAD = [
    # masses and inertias
    ("motorcycle.toml", "front_wheel.mass_kg", 0.0, "out of range (allowed 0 < mass_kg <= 100"),
    ("whipple_benchmark.toml", "rear_wheel.mass_kg", 0.0, "out of range (allowed 0 < mass_kg <= 100"),
    ("motorcycle.toml", "rear_wheel.spin_inertia_kgm2", 0.0, "out of range (allowed 0 < spin_inertia_kgm2"),
    ("whipple_benchmark.toml", "front_wheel.diametral_inertia_kgm2", 0.0,
     "out of range (allowed 0 < diametral_inertia_kgm2"),
    ("motorcycle.toml", "front_wheel.spin_inertia_kgm2", 0.9, "violates the triangle inequality"),
    ("motorcycle.toml", "rear_frame.mass_kg", 0.0, "must be positive: the model needs this body's mass"),
    ("whipple_benchmark.toml", "upper_fork.mass_kg", 0.0, "must be positive: the model needs this body's mass"),
    ("motorcycle.toml", "swingarm.inertia_kgm2", [0.0, 0.0, 0.0], "a rigid body's are positive"),
    ("motorcycle.toml", "swingarm.inertia_kgm2", [0.1, 0.6, 0.8], "violate the triangle inequality"),
    ("motorcycle.toml", "rider.ixz_kgm2", 8.0, "a rigid body's are non-negative (need Ixx, Iyy, Izz > 0 and "
                                               "ixz^2 < Ixx Izz)"),
    ("whipple_benchmark.toml", "rear_frame.inertia_kgm2", [-9.2, 11.0, 2.8],
     "out of range (allowed 0 <= inertia_kgm2[0] <= 100000 kg m^2; Ixx, Iyy, Izz", "rear_frame.inertia_kgm2[0] = -9.2"),
    ("motorcycle.toml", "lower_fork.mass_kg", 0.0, "a massless body has no inertia, yet inertia_kgm2"),
    ("xbw.toml", "chassis.inertia_kgm2", [300.0, 1100.0, 2000.0], "violate the triangle inequality"),
    ("xbw_fwd.toml", "chassis.inertia_kgm2", [0.0, 1100.0, 1200.0], "a rigid body's are positive"),
    ("eps_car.toml", "chassis.ixz_kgm2", 1100.0, "a rigid body's are positive (need Ixx, Iyy, Izz > 0 and "
                                                 "ixz^2 < Ixx Izz)"),
    ("xbw.toml", "front.unsprung_mass_kg", 0.0, "out of range (allowed 1 < unsprung_mass_kg <= 200"),
    ("eps_car.toml", "rear.wheel_spin_inertia_kgm2", 0.0, "out of range (allowed 0.05 < wheel_spin_inertia_kgm2"),
    # travel limits
    ("xbw.toml", "front.travel_m", [0.08, -0.08], "out of range (allowed -0.3 <= travel_m[0] < 0 m; rebound, bump",
     "front.travel_m[0] = 0.08"),
    ("eps_car.toml", "rear.travel_m", [-0.09, -0.01], "out of range (allowed 0 < travel_m[1] <= 0.3 m; rebound, bump",
     "rear.travel_m[1] = -0.01"),
    ("motorcycle.toml", "suspension.fork.design_travel_m", 0.2, "the design position must lie inside the stroke"),
    ("motorcycle.toml", "suspension.shock.design_travel_m", 0.06, "the design position must lie inside the stroke"),
    # linkages
    ("xbw.toml", "front.hardpoints.upper_rear", [0.12, 0.40, 0.43],
     "0.0 mm from upper_front: the upper arm's pivot axis is degenerate (need at least 10 mm)"),
    ("xbw.toml", "front.hardpoints.lower_rear", [0.145, 0.30, 0.17],
     "5.0 mm from lower_front: the lower arm's pivot axis is degenerate"),
    ("xbw.toml", "front.hardpoints.lower_ball", [0.0, 0.30, 0.17],
     "0.0 mm from the line lower_front-lower_rear: the lower arm (ball joint off its pivot axis) is degenerate"),
    ("xbw.toml", "front.hardpoints.upper_ball", [0.0, 0.62, 0.15], "0.0 mm from lower_ball: the kingpin axis"),
    ("xbw.toml", "front.hardpoints.tie_inner", [-0.12, 0.60, 0.22], "0.0 mm from tie_outer: the tie rod"),
    ("xbw.toml", "rear.hardpoints.strut_lower", [-2.42, 0.55, 0.75], "0.0 mm from strut_top: the strut axis"),
    ("xbw.toml", "rear.hardpoints.toe_inner", [-2.55, 0.62, 0.25], "0.0 mm from toe_outer: the toe link"),
    ("xbw_fwd.toml", "front.hardpoints.tie_outer", [0.0, 0.60, 0.22],
     "0.0 mm from kingpin: the steering arm (in the horizontal plane) is degenerate"),
    ("eps_car.toml", "front.hardpoints.spring_upper", [0.0, 0.70, 0.30], "0.0 mm from spring_lower: the spring"),
    ("motorcycle.toml", "suspension.shock.swingarm_mount_m", [0.42, 0.76], "0.0 mm from frame_mount_m"),
    ("xbw.toml", "steering.rack_travel_per_rad", 3.0e-3, "the overall steering ratio is 38.84, outside the "
                                                         "plausible 10 <= ratio <= 25"),
    ("xbw_fwd.toml", "front.hardpoints.tie_outer", [-0.05, 0.60, 0.22],
     "(front.hardpoints: a 50 mm steering arm) the overall steering ratio is 7.81",
     "steering.rack_travel_per_rad = 0.0064"),
    ("eps_car.toml", "eps.rack_travel_per_rad_m", 3.0e-2, "the overall steering ratio is 5.17"),
    # where the masses sit, the two-wheeler's geometry
    ("xbw.toml", "chassis.cg_m", [0.5, 0.0, 0.5], "must lie between the axles and above the ground"),
    ("eps_car.toml", "rear.hardpoints.wheel_centre", [-2.72, 0.09, 0.295], "the rear tyres overlap"),
    ("eps_car.toml", "front.hardpoints.wheel_centre", [0.0, 0.05, 0.295], "the front tyres overlap"),
    ("eps_car.toml", "chassis.cg_m", [-1.06, 0.0, -0.1], "must lie between the axles and above the ground"),
    ("motorcycle.toml", "rear_frame.cg_m", [-3.0, 0.52], "not between the tyre contacts"),
    ("motorcycle.toml", "geometry.wheelbase_m", 0.6, "the wheels overlap"),
    ("whipple_benchmark.toml", "geometry.swingarm_pivot_m", [1.5, 0.3], "must lie between the axles"),
    ("motorcycle.toml", "geometry.trail_m", -0.02, "with tyre forces the trail must be positive"),
    ("motorcycle.toml", "geometry.trail_m", 0.0, "with tyre forces the trail must be positive"),
]


def _id(row) -> str:
    return f"{Path(row[0]).stem}-{row[1]}={row[2]}"


@pytest.mark.parametrize("shipped", CARS + TWO_WHEELERS)
def test_every_shipped_vehicle_passes(shipped):
    cfg, _ = load(VEHICLES / shipped)
    assert cfg.id == Path(shipped).stem


@pytest.mark.parametrize("row", BAD, ids=[_id(r) for r in BAD])
def test_an_impossible_machine_is_refused_naming_file_key_value_and_rule(vehicles_dir, row):
    shipped, dotted, value, rule = row[:4]
    path = write_bad(vehicles_dir, shipped, dotted, value)
    with pytest.raises(ConfigError) as err:
        load(path)
    line = str(err.value)
    shown = repr(tuple(value)) if isinstance(value, list) else repr(value)
    named = row[4] if len(row) > 4 else f"{dotted} = {shown}"
    assert "\n" not in line
    assert line.startswith(f"{path}: {named}: "), line
    assert rule in line, line


def test_overlapping_front_and_rear_tyres_are_refused(vehicles_dir):
    """A wheelbase of 0.5 m with the prototype's 0.289 m tyres (two keys: the centre of mass must stay
    between the axles)."""
    text = with_key(with_key((VEHICLES / "xbw.toml").read_text(), "rear.hardpoints.wheel_centre", [-0.5, 0.675, 0.28]),
                    "chassis.cg_m", [-0.25, 0.0, 0.5])
    path = vehicles_dir / "xbw_short.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load(path)
    assert str(err.value) == (f"{path}: rear.hardpoints.wheel_centre = (-0.5, 0.675, 0.28): the front and rear tyres "
                              "overlap: wheelbase 0.5 m, need more than 2 x the tyre's unloaded radius (0.578 m)")


def test_the_steering_ratio_from_the_linkage_is_the_models():
    """The load-time ratio (the linkage solved 1 mm either side of the centred rack) against the model's own
    figure (`rtsim describe`: 18.2 for the prototype) and a lever rule: a vertical kingpin turned by a tie
    rod parallel to the rack, ratio = steering arm / rack travel per steering-wheel radian."""
    for shipped in CARS:
        cfg, _ = load_vehicle(VEHICLES / shipped)
        hp = {k: None if v is None else np.array(v, dtype=float) for k, v in cfg.front.hardpoints.model_dump().items()}
        geom = (DoubleWishbone if cfg.front.suspension == "double_wishbone" else VerticalSlider)(
            spin_axis=cfg.front.spin_axis(), **hp)
        rp = cfg.eps.rack_travel_per_rad_m if cfg.eps is not None else cfg.steering.rack_travel_per_rad
        ratio = steering_ratio(geom, rp)
        assert STEERING_RATIO_RANGE[0] <= ratio <= STEERING_RATIO_RANGE[1]
        if shipped == "xbw.toml":
            assert ratio == pytest.approx(18.2, abs=0.05)
        if shipped == "xbw_fwd.toml":         # arm 120 mm straight behind the kingpin, tie rod along y
            arm = math.dist(hp["tie_outer"][:2], hp["kingpin"][:2])
            assert ratio == pytest.approx(arm / rp, rel=1e-3)


# One bad file per kind through every command that opens a vehicle: one line, exit status 2, no traceback.
COMMANDS = {
    "motorcycle.toml": [
        ("eigen", "--vehicle", "{path}", "--speeds", "5,10"),
        ("statics", "--vehicle", "{path}"),
        ("run", "--vehicle", "{path}", "--scenario", "configs/scenarios/motorcycle_steady_turn.toml", "--out",
         "{tmp}/x.csv"),
        ("inverse", "--vehicle", "{path}", "--scenario", "configs/scenarios/motorcycle_steady_turn.toml", "--out",
         "{tmp}/inv.csv"),
        ("serve", "--vehicle", "{path}", "--no-hub", "--no-zenoh", "--can-interface", "virtual", "--can-channel",
         "cfg-physics-test", "--duration", "1"),
    ],
    "xbw.toml": [
        ("describe", "--vehicle", "{path}"),
        ("run", "--vehicle", "{path}", "--scenario", "configs/scenarios/step_steer_80kph.toml", "--out", "{tmp}/x.csv"),
        ("serve", "--vehicle", "{path}", "--no-hub", "--no-zenoh", "--can-interface", "virtual", "--can-channel",
         "cfg-physics-test", "--duration", "1"),
    ],
}
CLI_BAD = {"motorcycle.toml": ("front_wheel.mass_kg", 0.0),
           "xbw.toml": ("front.hardpoints.upper_rear", [0.12, 0.40, 0.43])}


@pytest.mark.parametrize("shipped, args", [(s, a) for s, cmds in COMMANDS.items() for a in cmds],
                         ids=[f"{Path(s).stem}-{a[0]}" for s, cmds in COMMANDS.items() for a in cmds])
def test_every_command_ends_with_the_line_not_a_traceback(vehicles_dir, tmp_path, shipped, args):
    dotted, value = CLI_BAD[shipped]
    path = write_bad(vehicles_dir, shipped, dotted, value)
    argv = [a.format(path=path, tmp=tmp_path) for a in args]
    p = subprocess.run([sys.executable, "-m", "rtsim.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                       timeout=300)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr + p.stdout
    shown = repr(tuple(value)) if isinstance(value, list) else repr(value)
    assert len(lines) == 1 and lines[0].startswith(f"rtsim: error: {path}: {dotted} = {shown}: "), p.stderr
