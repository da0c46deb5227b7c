"""The vehicle kit's vertical slider against its analytic kinematics (pure slide, crank-rod steering), and
the second assembly of the four-wheel car (configs/vehicles/xbw_fwd.toml: front-wheel drive, vertical
sliders), which is a config file only: its powertrain drives the front wheels, its sliders keep camber."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.vehicle.kit.linkages import (OUT_AXIS, OUT_CENTRE, OUT_ROT_S, VerticalSlider, _solve_vertical_slider,
                                        rack_direction, solve_corner)
from rtsim.vehicle.offline import prepare, run

FWD = "configs/vehicles/xbw_fwd.toml"


def _slider(steered: bool) -> VerticalSlider:
    a = np.array
    kw = dict(kingpin=a([0.0, 0.60, 0.28]), tie_outer=a([-0.12, 0.60, 0.22]), tie_inner=a([-0.12, 0.32, 0.22])) \
        if steered else {}
    return VerticalSlider(wheel_centre=a([0.0, 0.675, 0.28]), spring_lower=a([0.0, 0.55, 0.25]),
                          spring_upper=a([0.0, 0.55, 0.65]), spin_axis=a([0.0, 1.0, 0.0]), **kw)


def test_unsteered_slider_slides_vertically_with_constant_camber():
    kin = solve_corner(_slider(False))
    for z in (-0.07, -0.02, 0.0, 0.03, 0.07):
        assert kin.evaluate(OUT_CENTRE, z) == pytest.approx([0.0, 0.675, 0.28 + z], abs=1e-9)
        assert kin.evaluate(OUT_AXIS, z) == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
        assert kin.spring_length(z) == pytest.approx(0.40 - z, abs=1e-9)
    assert not kin.steered


def test_steered_slider_follows_the_crank_rod_law():
    """Steering arm of radius r about the vertical kingpin, tie rod of length L from the rack point:
    the arm end lies on both circles (plan view), so the steer angle is analytic in the rack travel."""
    g = _slider(True)
    kin = solve_corner(g)
    kp, to, ti = g.kingpin[:2], g.tie_outer[:2], g.tie_inner[:2]
    r, rod = np.linalg.norm(to - kp), np.linalg.norm(to - ti)
    phi0 = math.atan2(*(to - kp)[::-1])
    for s in (-0.05, -0.02, 0.01, 0.04):
        p = ti + s * rack_direction(g)[:2]
        d = p - kp
        dist = np.linalg.norm(d)
        # arm end angle: the intersection of the two circles on the assembled branch
        ang = math.atan2(d[1], d[0]) - math.acos((r * r + dist * dist - rod * rod) / (2 * r * dist))
        ang2 = math.atan2(d[1], d[0]) + math.acos((r * r + dist * dist - rod * rod) / (2 * r * dist))
        delta = min(((a - phi0 + math.pi) % (2 * math.pi) - math.pi for a in (ang, ang2)), key=abs)
        assert _solve_vertical_slider(g, 0.0, s, np.zeros(6))[2] == pytest.approx(delta, abs=1e-12)
        axis = kin.evaluate(OUT_AXIS, 0.0, s)          # the polynomial fit, within its reported error
        assert math.atan2(-axis[0], axis[1]) == pytest.approx(delta, abs=kin.fit_error)
        # the knuckle turns about the vertical only
        rate = kin.evaluate(OUT_ROT_S, 0.0, s)
        assert abs(rate[0]) < 1e-6 and abs(rate[1]) < 1e-6
    # steering left (positive steer) for positive rack travel
    assert math.atan2(-kin.evaluate(OUT_AXIS, 0.0, 0.03)[0], kin.evaluate(OUT_AXIS, 0.0, 0.03)[1]) > 0.0


def test_front_wheel_drive_car_pulls_with_its_front_wheels():
    sim, sc = prepare(FWD, load_scenario("configs/scenarios/straight_line.toml", check_files=True))
    res = run(sim, sc)
    t, v = res.column("time"), res.column("speed")
    accelerating = (np.gradient(v, t) > 0.5) & (v > 1.0)
    assert accelerating.sum() > 10
    front = res.column("tyre_fx_fl")[accelerating] + res.column("tyre_fx_fr")[accelerating]
    rear = res.column("tyre_fx_rl")[accelerating] + res.column("tyre_fx_rr")[accelerating]
    mass = sim.vm.config.chassis.mass_kg + 4 * 30.0
    # the front tyres carry the whole tractive force; the rear ones only roll (resistance < 2 % of weight)
    assert np.all(front > 0.5 * mass) and np.all(np.abs(rear) < 0.02 * mass * 9.81)
