"""No valid command sequence breaks a shipped vehicle (rtsim.robustness): commands drawn by hypothesis
inside each vehicle's DBC ranges (steps, ramps, chatter, lock to lock, full throttle with full brake),
from standstill to the vehicle's top speed, on every shipped road it runs on, end without a model
failure, with finite state and with the mechanical energy inside the bound of rtsim.robustness.harness.
A two-wheeler's fall is a defined end of a ride, not a failure.

CI runs a reduced draw (``CI_RIDES`` rides per vehicle of at most 1.5 s, derandomized: the same rides on
every run); ``rtsim bench --suite fuzz`` runs the full count. Every failing ride ever found, and the
cases the issue reported, are kept in tests/data/fuzz_regressions.json and replayed here as drawn; a
case whose root cause is still open carries an ``open`` note and is a strict expected failure (it must
keep failing until fixed; then the note goes)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings

from rtsim.robustness.commands import Ride, Segment, command_space, expand, ride_strategy
from rtsim.robustness.harness import FuzzTarget, shipped_vehicles

ROOT = Path(__file__).resolve().parents[1]
REGRESSIONS = ROOT / "tests" / "data" / "fuzz_regressions.json"
CI_RIDES = 12
VEHICLES = [p.stem for p in shipped_vehicles()]
_TARGETS: dict[str, FuzzTarget] = {}


def target(name: str) -> FuzzTarget:
    if name not in _TARGETS:
        _TARGETS[name] = FuzzTarget(ROOT / "configs" / "vehicles" / f"{name}.toml")
    return _TARGETS[name]


def _assert_survives(name: str, ride: Ride) -> None:
    res = target(name).ride(ride)
    where = f"{name}: {res.error_type} {res.failure}\nride: {ride.dumps()}"
    assert not res.failed, where
    assert res.finite, where
    assert res.energy_ratio <= 1.0, where
    assert res.outcome in ("ok", "fell"), where
    if res.outcome == "fell":
        assert target(name).can_fall, where


# ---- the command space is the DBC's --------------------------------------------------------------------
def test_command_space_is_read_from_the_dbc():
    """Ranges and periods as the DBC declares them (checked against the DBC's text, not cantools)."""
    import re

    for dbc in sorted((ROOT / "configs" / "can").glob("*.dbc")):
        text = dbc.read_text()
        space = command_space(dbc)
        for c in space.commands:
            m = re.search(rf"SG_ {c.name} : [^\[]*\[([-0-9.eE]+)\|([-0-9.eE]+)\]", text)
            assert m, f"{dbc.name}: {c.name}"
            assert (c.lo, c.hi) == (float(m.group(1)), float(m.group(2)))
            fid = re.search(rf"BO_ (\d+) \w+: \d+ ECU\n(?: SG_[^\n]*\n)*? SG_ {c.name} ", text).group(1)
            period = re.search(rf'BA_ "GenMsgCycleTime" BO_ {fid} (\d+);', text).group(1)
            assert c.period_s == pytest.approx(float(period) * 1e-3)
        assert "lockstep_steps" not in space.names


def test_eps_car_driver_inputs_are_ranged_by_the_dbc_sensor_signals():
    space = target("eps_car").space
    by = {c.name: c for c in space.commands}
    assert by["motor_current_cmd"].source == "bus" and (by["motor_current_cmd"].lo, by["motor_current_cmd"].hi) == (-120, 120)
    assert by["steering_wheel_angle_cmd"].source == "driver"
    assert (by["steering_wheel_angle_cmd"].lo, by["steering_wheel_angle_cmd"].hi) == (-11.0, 11.0)


def test_expand_shapes():
    segs = (Segment("step", 2, (1.0,)), Segment("ramp", 4, (3.0,)), Segment("chatter", 4, (0.0,), 1))
    out = expand(segs, [0.0])[:, 0]
    assert out.tolist() == [1.0, 1.0, 1.5, 2.0, 2.5, 3.0, 0.0, 3.0, 0.0, 3.0]


def test_ride_round_trips_through_json():
    r = Ride("flat", 12.5, (Segment("chatter", 7, (1.0, -2.0), 3),), rider=False, eps_external=False)
    assert Ride.from_json(json.loads(r.dumps())) == r


def test_a_broken_energy_bound_is_a_failure(monkeypatch):
    """The check can fail: with an allowance of 1 J (no drive power, no springs, no tolerance), the
    engine's work at full throttle from standstill breaks the bound and the ride is reported failed."""
    from rtsim.robustness import harness

    t = target("xbw")
    monkeypatch.setattr(harness, "SPRING_DROP_M", 0.0)
    monkeypatch.setattr(harness, "TOLERANCE_SHARE", 0.0)
    monkeypatch.setattr(t, "p_max", 0.0)
    monkeypatch.setattr(t, "e_flywheel", 1.0)
    res = t.ride(Ride("flat", 0.0, (Segment("step", 100, (1.4, 0.0, 0.0)),)))
    assert res.failed and res.error_type == "EnergyBound"


# ---- regressions: every failure ever found, and the cases -----------------------------------------
def _regressions():
    """Each kept case; one whose root cause is still open (its ``open`` says what is known) is a strict
    expected failure: it must keep failing until fixed, then the mark must go."""
    return [pytest.param(c["vehicle"], Ride.from_json(c["ride"]), id=f"{c['vehicle']}-{i}-{c['ride'].get('note', '')}",
                         marks=[pytest.mark.xfail(strict=True, reason=c["open"])] if c.get("open") else [])
            for i, c in enumerate(json.loads(REGRESSIONS.read_text()))]


@pytest.mark.parametrize("vehicle,ride", _regressions())
def test_regression_ride_survives(vehicle, ride):
    _assert_survives(vehicle, ride)


# ---- the reduced draw --------------------------------------------------------------------------------
@pytest.mark.parametrize("vehicle", VEHICLES)
def test_drawn_command_sequences_never_break_the_model(vehicle):
    t = target(vehicle)
    strategy = ride_strategy(t.space, t.roads, t.top_speed, max_segment_s=0.5, max_segments=3,
                             rider_optional=t.rig.rider_optional, eps_optional=t.eps)

    # no shrinking: a failure is reported as drawn (its ride JSON replays it), in bounded time
    @settings(max_examples=CI_RIDES, derandomize=True, deadline=None, database=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck))
    @given(strategy)
    def check(ride):
        _assert_survives(vehicle, ride)

    check()
