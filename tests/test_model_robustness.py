"""Valid commands never break a car model (issue: a steering-wheel step inside the DBC's range made the
X-by-wire car fail, a +-6 rad step the EPS car).

Each case drives a car with commands inside its DBC's ranges (steering-wheel angle +-11 rad, throttle
0 .. 1.4 rad, brake 0 .. 12 000 kPa) and asserts:

- no model failure (the step raises nothing) and a finite state;
- bounded energy: the kinetic energy 1/2 qd^T M qd (M: the model's constant mass matrix in its
  natural coordinates) never exceeds the initial kinetic energy plus what the actuators could have put
  in since the start, (P_engine + P_steer) t, plus the potential energy released, m g (z_0 - z), plus
  the elastic energy the tyres and springs hold at the static loads W_i (the car is placed near, not
  at, its equilibrium and may release it), sum W_i^2 / (2 C_z) + (W_i / 0.6)^2 / (2 k_i) (C_z the
  tyre's vertical stiffness, k_i the spring's, 0.6 the smallest installation ratio of the shipped
  linkages);
  P_engine the engine map's full-load peak power (rtsim.vehicle.kit.powertrain.default_engine_map),
  P_steer a bound on the steering actuator's power (the steer-by-wire motor: its torque limit at its
  no-load speed is far below 2 kW; the EPS motor: supply voltage x current limit, ~1 kW);
- the rack end stop as a stop: the rack never leaves the range the suspension's kinematics are fitted
  over, and held against a stop it sits there with at most the stop's static deflection under the
  steering's largest force (motor torque limit through the reduction, over the rack travel per pinion
  radian), F_max / k_stop, plus 10 % and 0.2 mm for the tyres' share.

The cases are the issue's (steps to +-9 and +-11 rad at 10 and 36 m/s with full throttle, the standing
+-11 rad steps, the EPS car's +-6 rad step at 20 m/s) and chatter from lock to lock, full throttle and
full brake at once, a step on the 5 % grade. Simulated times are short (1.5 .. 3 s).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.road.config import load_road
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.layout import G
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_SELECTOR
from rtsim.vehicle.kit.powertrain import default_engine_map
from rtsim.vehicle.kit.steering import steering_config
from rtsim.vehicle.kit.tyre.tir import P_VERTICAL_STIFFNESS

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-3
THROTTLE_MAX = 1.4      # rad, DBC range of throttle_angle_cmd
BRAKE_MAX = 12000.0     # kPa, DBC range of brake_pressure_cmd
FIT_RACK = 0.07         # m, the rack range the steer-by-wire cars' corner kinematics are fitted over

_models: dict = {}


def _model(vehicle: str):
    if vehicle not in _models:
        cfg, base = load_vehicle(ROOT / "configs" / "vehicles" / f"{vehicle}.toml")
        _models[vehicle] = build_vehicle(cfg, base)
    return _models[vehicle]


def _engine_peak_power() -> float:
    """W: the full-load curve's peak of torque x speed."""
    throttle, speed, table = default_engine_map()
    wot = table[-1]
    return max(t * w for t, w in zip(wot, speed))


def _spring_rate(spring) -> float:
    """N/m: a linear spring's rate, or a spring table's smallest positive slope (more energy)."""
    if spring.stiffness_n_per_m is not None:
        return spring.stiffness_n_per_m
    x, f = np.asarray(spring.spring_table.x), np.asarray(spring.spring_table.force_n)
    slopes = np.diff(f) / np.diff(x)
    return float(slopes[slopes > 0].min())


class Run:
    """A car on a road, stepped with held commands, checking energy and recording the rack."""

    def __init__(self, vehicle: str, speed: float, road="flat", position=(0.0, 0.0)):
        """`road`: a shipped road's name or a Road."""
        if isinstance(road, str):
            road = load_road(ROOT / "configs" / "roads" / f"{road}.toml")
        self.sim = VehicleSim(_model(vehicle), road, DT, speed=speed, position=position)
        vm = self.sim.vm
        self.mass = vm.mech.mass_dense
        self.m_total = vm.config.chassis.mass_kg + 2 * vm.config.front.unsprung_mass_kg \
            + 2 * vm.config.rear.unsprung_mass_kg
        self.p_in = _engine_peak_power() + 2000.0
        self.ir = int(vm.vehicle.steer_idx[1])
        self.iz = int(vm.vehicle.chassis_idx[2])
        self.e0 = self.kinetic() + self._elastic_at_static_loads()
        self.z0 = float(self.sim.data.q[self.iz])
        self.rack = []

    def _elastic_at_static_loads(self) -> float:
        vm = self.sim.vm
        loads = np.asarray(vm.static_loads, dtype=float)
        cz = float(self.sim.tp[P_VERTICAL_STIFFNESS])
        k = np.array([_spring_rate(vm.config.front.spring)] * 2 + [_spring_rate(vm.config.rear.spring)] * 2)
        return float(np.sum(loads ** 2 / (2.0 * cz) + (loads / 0.6) ** 2 / (2.0 * k)))

    def kinetic(self) -> float:
        qd = self.sim.data.qd
        return 0.5 * float(qd @ self.mass @ qd)

    def hold(self, seconds: float, steer: float, throttle: float = 0.0, brake: float = 0.0) -> None:
        io = self.sim.io
        io.commands[CMD_STEER] = steer
        io.commands[CMD_THROTTLE] = throttle
        io.commands[CMD_BRAKE] = brake
        for _ in range(int(round(seconds / DT / 10))):
            self.sim.step(10)      # raises a typed SimulationError on a model failure
            d = self.sim.data
            assert np.all(np.isfinite(d.q)) and np.all(np.isfinite(d.qd)), f"non-finite state at t = {d.t[0]:.3f} s"
            t = float(d.t[0])
            released = self.m_total * G * max(0.0, self.z0 - float(d.q[self.iz]))
            bound = self.e0 + self.p_in * t + released
            ke = self.kinetic()
            assert ke <= bound, f"kinetic energy {ke:.0f} J above {bound:.0f} J at t = {t:.3f} s"
            self.rack.append(float(d.q[self.ir]))


def _stop_deflection(vehicle: str) -> tuple[float, float]:
    """(rack travel, static deflection F_max / k) of a steer-by-wire car's end stops (m)."""
    st = steering_config(_model(vehicle).config.steering or None)
    f_max = st.motor_torque_limit * st.reduction_ratio * st.reduction_efficiency / st.rack_travel_per_rad
    return st.rack_travel, f_max / st.rack_stop_stiffness


def _check_rack(run: Run, vehicle: str, settled: int = 0) -> None:
    travel, defl = _stop_deflection(vehicle)
    rack = np.abs(np.array(run.rack))
    assert rack.max() < FIT_RACK, f"rack at {rack.max():.4f} m, beyond the fitted +-{FIT_RACK} m"
    if settled:
        held = rack[-settled:]
        assert held.max() - travel <= 1.1 * defl + 2e-4, (
            f"held on its stop the rack passes its travel by {(held.max() - travel) * 1e3:.2f} mm, "
            f"the static deflection is {defl * 1e3:.2f} mm")
        assert held.min() > travel - 1e-3, "a command past the lock holds the rack on its stop"


@pytest.mark.parametrize("vehicle", ["xbw", "xbw_fwd"])
@pytest.mark.parametrize("speed", [10.0, 36.0])
@pytest.mark.parametrize("angle", [9.0, -9.0, 11.0, -11.0])
def test_steering_wheel_step_with_full_throttle(vehicle, speed, angle):
    """The issue's steps: 0 -> +-9 and +-11 rad at 10 and 36 m/s with full throttle."""
    run = Run(vehicle, speed)
    run.hold(0.2, 0.0, THROTTLE_MAX)
    run.hold(1.8, angle, THROTTLE_MAX)
    _check_rack(run, vehicle)


@pytest.mark.parametrize("vehicle", ["xbw", "xbw_fwd"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_standing_steps_to_the_locks(vehicle, sign):
    """The issue's standing case: no throttle, no brake (the automatic creeps), +-11 rad and then the
    other lock."""
    run = Run(vehicle, 0.0)
    run.hold(0.1, 0.0)
    run.hold(1.4, 11.0 * sign)
    run.hold(1.6, -11.0 * sign)
    _check_rack(run, vehicle)


def test_braked_at_standstill_steering_to_the_lock():
    """Standing on the brakes (3 MPa) and steering to the lock: the wheels turn about their kingpins on
    locked spin (it failed at 0.2 s, Newton crawling on the locked wheels' brake band)."""
    run = Run("xbw", 0.0)
    run.hold(0.1, 0.0, brake=3000.0)
    run.hold(1.5, 11.0, brake=3000.0)
    run.hold(1.0, -11.0, brake=3000.0)
    _check_rack(run, "xbw")


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_held_against_its_stop_the_rack_deflects_it_statically(sign):
    """At standstill in neutral (no creep), commanded past the lock: once the motion has died out the
    rack sits on its stop pressed by the motor's full force, F_max / k_stop past its travel."""
    run = Run("xbw", 0.0)
    run.sim.io.extra[EX_SELECTOR] = 0.0
    run.hold(0.1, 0.0)
    run.hold(2.5, 11.0 * sign)
    _check_rack(run, "xbw", settled=30)         # the last 0.3 s


@pytest.mark.parametrize("vehicle", ["xbw", "xbw_fwd"])
def test_lock_to_lock_chatter(vehicle):
    """Full lock to full lock every 0.1 s at 15 m/s with half throttle."""
    run = Run(vehicle, 15.0)
    for k in range(20):
        run.hold(0.1, 11.0 if k % 2 == 0 else -11.0, 0.7)
    _check_rack(run, vehicle)


@pytest.mark.parametrize("vehicle", ["xbw", "xbw_fwd"])
def test_full_throttle_and_full_brake_at_once_in_a_turn(vehicle):
    """12 MPa and wide-open throttle at 20 m/s in a turn: the front wheels lock (it failed at 0.39 s,
    Newton crawling ~7 % an iteration onto the locked wheels' brake band)."""
    run = Run(vehicle, 20.0)
    run.hold(0.2, 0.0)
    run.hold(2.0, 8.0, THROTTLE_MAX, BRAKE_MAX)
    speed = float(np.linalg.norm(run.sim.data.qd[run.sim.vm.vehicle.chassis_idx[:3]]))
    assert speed < 20.0, "full brake wins over full throttle"


def test_step_to_the_lock_on_the_grade():
    run = Run("xbw", 10.0, road="grade_5pct")
    run.hold(0.2, 0.0, THROTTLE_MAX)
    run.hold(1.5, -11.0, THROTTLE_MAX)
    _check_rack(run, "xbw")


@pytest.mark.parametrize("first", [6.0, -6.0])
def test_eps_car_six_radian_steps_at_20_mps(first):
    """The issue's EPS case: +-6 rad at 20 m/s (the driver imposes the angle), the reversal at 2 s; it
    failed at 2.43 s (Newton cycling across the steering's friction and efficiency kinks)."""
    run = Run("eps_car", 20.0)
    run.hold(1.0, 0.0)
    run.hold(1.0, first)
    run.hold(0.7, -first)
    travel = _model("eps_car").config.eps.rack_travel_m
    assert np.abs(np.array(run.rack)).max() < travel, "6 rad is inside the EPS rack's travel"


@pytest.mark.parametrize("throttle", [0.0, THROTTLE_MAX])
def test_eps_car_past_the_lock_and_back_at_20_mps(throttle):
    """The driver's hands impose +11 rad, past the EPS rack's lock (7.2 rad), then -11 rad: the rack sits
    on its stop under the twisted torsion bar and the assist (it failed at 1.2 s: Newton jumping across
    the transmission's driving/driven switch, a ~9 kN step over 0.2 mm/s at the stalled rack)."""
    run = Run("eps_car", 20.0)
    run.hold(0.5, 0.0, throttle)
    run.hold(1.0, 11.0, throttle)
    run.hold(1.0, -11.0, throttle)
    assert np.abs(np.array(run.rack)).max() > _model("eps_car").config.eps.rack_travel_m, "the rack reached its stop"


def test_eps_car_lock_to_lock_chatter():
    """Full lock to full lock every 0.15 s at 10 m/s."""
    run = Run("eps_car", 10.0)
    for k in range(12):
        run.hold(0.15, 11.0 if k % 2 == 0 else -11.0, 0.7)


def _campus_without_ground():
    """The campus survey mesh with no ground beyond it (a mesh road without off-survey values): a car
    that leaves it falls."""
    from rtsim.road.config import read_road_config
    from rtsim.road.model import make_mesh
    from rtsim.road.survey import read_survey, survey_to_mesh

    path = ROOT / "configs" / "roads" / "campus.toml"
    cfg = read_road_config(path)
    mesh = survey_to_mesh(read_survey(path.parent / cfg.survey), cfg.grid_spacing, cfg.alpha_radius, cfg.mu,
                          cfg.rolling_resistance)
    return make_mesh(mesh.vertices, mesh.triangles, mesh.tri_mu, mesh.tri_rr, cell_size=cfg.grid_spacing,
                     smooth_normals=cfg.smooth_normals)


def test_leaving_the_campus_survey_the_car_stays_on_the_ground():
    """10 m/s, full throttle, +11 rad then -11 rad on the campus lane: the car leaves the surveyed lane
    at about 1.5 s; the ground continues beyond the survey (rtsim.road.model, "Off the survey"), so it
    drives on with its wheels loaded, inside its energy bound and with the rack inside its stops."""
    run = Run("xbw", 10.0, road="campus")
    run.hold(0.5, 0.0, THROTTLE_MAX)
    run.hold(1.0, 11.0, THROTTLE_MAX)
    run.hold(1.1, -11.0, THROTTLE_MAX)
    sim = run.sim
    x, y = (float(sim.data.q[k]) for k in sim.vm.vehicle.chassis_idx[:2])
    from rtsim.road.query import NQUERY, road_query
    assert road_query(sim.road, x, y, np.zeros(NQUERY)) == -1, f"the car is still on the survey at ({x:.1f}, {y:.1f})"
    assert np.all(sim.vd.tyre[:, 2] > 0.0), "every wheel on the ground beyond the survey"
    _check_rack(run, "xbw")


def test_off_a_mesh_without_ground_the_wheels_hang_on_their_rebound_stops():
    """The same ride on the campus mesh with no ground beyond it: the car leaves the surveyed mesh at
    about 1.5 s and falls with its wheels in the air (it failed at 2.0 s: the front travel drooped to
    -0.14 m, outside the linkage fit, and the extrapolated kinematics threw the rack between its stops).
    The hanging wheels rest on their rebound stops, inside the fitted travel."""
    run = Run("xbw", 10.0, road=_campus_without_ground())
    run.hold(0.5, 0.0, THROTTLE_MAX)
    run.hold(1.0, 11.0, THROTTLE_MAX)
    run.hold(1.1, -11.0, THROTTLE_MAX)
    sim = run.sim
    cfg = sim.vm.config
    assert np.all(sim.vd.tyre[:, 2] == 0.0), "the car has left the road: every wheel in the air"
    for i in range(4):
        lo = (cfg.front if i < 2 else cfg.rear).travel_m[0]
        z = float(sim.data.q[sim.vm.vehicle.corner_idx[i, 3]])
        assert lo < z, f"wheel {i} hangs at {z:.3f} m, beyond the fitted rebound travel {lo} m"
    _check_rack(run, "xbw")


# ---- rides the command fuzzing found (issue 29): written out as command sequences ----------------------
FRAME = 0.01      # s, the command period of the cars' DBC


def _frames(segments, start=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The (throttle rad, brake kPa, steering-wheel rad) of each 10 ms command frame of a sequence of
    segments (shape, frames, values, period) from ``start``: "step" holds the values, "ramp" goes
    linearly from the previous frame's values to them (reaching them on its last frame), "chatter"
    alternates the values and the previous ones every ``period`` frames, starting with the values."""
    rows, prev = [], np.asarray(start, dtype=float)
    for shape, n, values, period in segments:
        target = np.asarray(values, dtype=float)
        if shape == "step":
            block = np.repeat(target[None, :], n, axis=0)
        elif shape == "ramp":
            block = prev + (np.arange(1, n + 1) / n)[:, None] * (target - prev)
        else:
            on = ((np.arange(n) // period) % 2 == 0)[:, None]
            block = np.where(on, target, prev)
        rows.append(block)
        prev = block[-1]
    return np.concatenate(rows)


def _ride(vehicle: str, road: str, speed: float, segments) -> Run:
    """The car placed as the HIL service places it (at (2, 0) heading +x, rolling at ``speed``, brakes
    released), each frame's commands held for 10 ms, the energy bound checked each frame."""
    run = Run(vehicle, speed, road, position=(2.0, 0.0))
    for throttle, brake, steer in _frames(segments):
        run.hold(FRAME, steer, throttle, brake)
    return run


# After a lock with the brakes on was released at ~29 m/s with the front tyres sliding, the rack rang on
# the torsion bar at ~50 Hz, growing to 15 m/s of rack speed, hit its stops and left the fitted
# kinematics (Newton failed at 1.137 s and 1.028 s): the wheels' inertia about their steering axes
# was missing from the rack (~5 kg on its diagonal instead of ~70 kg).
FUZZ_FLAT_30 = {
    "ramp_in_then_lock_with_brakes": [
        ("ramp", 60, (0.08393904481019925, 12000.0, 4.691521849638697), 10),
        ("step", 16, (0.7778439616631586, 12000.0, -11.0), 7),
        ("step", 100, (1.2444435975487786, 0.0, 0.0), 7),
        ("step", 16, (0.7778439616631586, 12000.0, -11.0), 7)],
    "throttle_then_lock_with_brakes_twice": [
        ("ramp", 60, (1.2444435975487786, 0.0, 0.0), 10),
        ("step", 16, (0.7778439616631586, 12000.0, -11.0), 7),
        ("step", 100, (1.2444435975487786, 0.0, 0.0), 7),
        ("step", 16, (0.7778439616631586, 12000.0, -11.0), 7)],
    "lock_released_into_a_throttle_ramp": [
        ("ramp", 60, (0.08393904481019925, 12000.0, 4.691521849638697), 10),
        ("step", 16, (0.7778439616631586, 12000.0, -11.0), 7),
        ("step", 100, (1.2444435975487786, 0.0, 0.0), 7),
        ("ramp", 36, (1.4, 3315.135505540702, -11.0), 6)],
}


@pytest.mark.parametrize("name", sorted(FUZZ_FLAT_30))
def test_fuzz_a_lock_with_brakes_released_at_30_mps(name):
    run = _ride("xbw", "flat", 30.21401309317024, FUZZ_FLAT_30[name])
    _check_rack(run, "xbw")


def test_fuzz_brake_chatter_at_49_mps_on_the_campus_lane():
    """Full brake chattered with +4.1 rad, then full throttle and brake at once at 49 m/s (it failed at
    1.057 s, the same ringing rack)."""
    run = _ride("xbw", "campus", 48.86921905584122, [
        ("chatter", 84, (0.28653881333227466, 12000.0, 4.093823962140098), 6),
        ("step", 90, (1.4, 12000.0, 2.6339002253199997), 5),
        ("chatter", 77, (1.4, 0.0, 0.0), 4),
        ("chatter", 66, (1.4, 12000.0, 0.0), 4)])
    _check_rack(run, "xbw")
