"""The formulation on small mechanisms with analytic answers: assembly, typed failures, rheonomic
drivers, linear oscillators (where the trapezoidal rule has a closed-form discrete solution) and
redundant constraints."""
from __future__ import annotations

import numpy as np
import pytest

import references as R
from rtsim.errors import AssemblyError, ConvergenceError, NonFiniteForceError, SimulationError
from rtsim.mbs import MechanismBuilder, Settings, Simulation
from rtsim.mbs.model import ST_MAX_PHI, ST_MAX_PHID

G = 9.81


def pendulum_builder(x0: float = 1.0, length: float | None = None, settings: Settings | None = None,
                     name: str = "pend") -> tuple[MechanismBuilder, object, object]:
    kw = {} if settings is None else {"settings": settings}
    b = MechanismBuilder(dim=2, name=name, **kw)
    o = b.fixed_point((0.0, 0.0), "O")
    p = b.point("P1", (x0, 0.0), velocity=(0.0, None))
    b.point_mass(p, 1.0)
    b.distance(o, p, length=length)
    b.gravity((0.0, -G))
    return b, o, p


# ---- (a), (b) assembly ------------------------------------------------------------------------------
def test_inconsistent_initial_coordinates_are_assembled():
    b, o, p = pendulum_builder(x0=1.1, length=1.0)
    mech = b.compile()
    sim = Simulation(mech, 1e-3)
    phi, _ = sim.constraint_jacobian(sim.data.q)
    assert np.max(np.abs(phi)) < 1e-10
    # minimum-norm correction: the point moves radially from (1.1, 0) to (1, 0)
    assert sim.position_correction == pytest.approx(0.1, abs=1e-9)
    np.testing.assert_allclose(sim.data.q, [1.0, 0.0], atol=1e-10)
    # the assembled pendulum then swings like the reference one
    traj = sim.run(t_end=1.0, stride=100)
    ref = R.pendulum_reference(traj.t)
    assert np.max(np.abs(traj.q[:, mech.coordinate("P1.x")] - ref["x_P1"])) < 1e-3
    assert np.max(np.abs(traj.q[:, mech.coordinate("P1.y")] - ref["y_P1"])) < 1e-3


def test_no_assembly_reports_violated_constraint():
    b, o, p = pendulum_builder(x0=1.1, length=1.0)
    mech = b.compile()
    with pytest.raises(AssemblyError, match="distance") as exc:
        Simulation(mech, 1e-3, assemble=False)
    assert "distance(O, P1)" in str(exc.value)
    # consistent coordinates need no assembly
    b2, _, _ = pendulum_builder(x0=1.0, length=1.0)
    sim = Simulation(b2.compile(), 1e-3, assemble=False)
    assert sim.position_correction == 0.0


def test_impossible_assembly_raises_naming_a_constraint():
    b = MechanismBuilder(dim=2, name="impossible")
    o = b.fixed_point((0.0, 0.0), "O")
    f = b.fixed_point((5.0, 0.0), "F")
    p = b.point("P", (0.5, 0.1))
    b.point_mass(p, 1.0)
    b.distance(o, p, length=1.0, name="near O")
    b.distance(f, p, length=1.0, name="near F")
    mech = b.compile()
    with pytest.raises(AssemblyError) as exc:
        Simulation(mech, 1e-3)
    msg = str(exc.value)
    assert "'near O'" in msg or "'near F'" in msg, msg
    assert "impossible" in msg          # the mechanism is named too


def test_inconsistent_prescribed_velocity_raises():
    b = MechanismBuilder(dim=2, name="pv")
    o = b.fixed_point((0.0, 0.0), "O")
    p = b.point("P1", (1.0, 0.0), velocity=(1.0, 0.0))   # radial velocity on a rigid link
    b.point_mass(p, 1.0)
    b.distance(o, p)
    with pytest.raises(AssemblyError, match="distance"):
        Simulation(b.compile(), 1e-3)


# ---- (c), (d) typed failures --------------------------------------------------------------------------
def _crank_with_angle(name: str):
    b = MechanismBuilder(dim=2, name=name)
    o = b.fixed_point((0.0, 0.0), "O")
    p = b.point("P", (1.0, 0.0))
    theta = b.angle("theta", 0.0)
    b.angle2d(theta, p, o)
    b.rod("crank", o, p, 1.0)
    b.gravity((0.0, -G))
    return b, o, p, theta


@pytest.mark.parametrize("kind", ["coordinate_force", "spring"])
def test_nan_force_parameter_raises_naming_coordinate(kind):
    b, o, p, theta = _crank_with_angle("nanforce")
    if kind == "coordinate_force":
        b.coordinate_force(theta, constant=float("nan"))
        coord = "theta"
    else:
        anchor = b.fixed_point((0.0, -2.0), "K")
        b.spring(p, anchor, stiffness=float("nan"))
        coord = "P."
    mech = b.compile()
    with pytest.raises(NonFiniteForceError) as exc:
        # detected when the initial accelerations are computed, or else in the first step
        sim = Simulation(mech, 1e-3)
        sim.run(t_end=0.1)
    e = exc.value
    msg = str(e)
    assert f"'{coord}" in msg, msg
    assert "t = " in msg
    assert e.step in (0, 1) and e.time == pytest.approx(e.step * 1e-3, abs=1e-12)


def test_nan_external_force_mid_run_raises_with_step_and_time():
    """A non-finite external force (the HIL input) arriving after 10 good steps stops the run at step
    11, naming the coordinate; it never comes back with NaN coordinates."""
    b, o, p = pendulum_builder()
    mech = b.compile()
    sim = Simulation(mech, 1e-3)
    good = sim.run(steps=10)
    assert np.all(np.isfinite(good.q))
    k = mech.coordinate("P1.y")
    sim.data.q_ext[k] = np.nan
    with pytest.raises(NonFiniteForceError) as exc:
        sim.run(steps=10)
    e = exc.value
    assert e.step == 11
    assert e.time == pytest.approx(0.011, abs=1e-12)
    msg = str(e)
    assert "'P1.y'" in msg and "step 11" in msg and "0.011" in msg, msg
    assert sim.steps == 10


def test_newton_iteration_limit_raises_convergence_error():
    b, o, p = pendulum_builder(settings=Settings(max_iter=1))
    mech = b.compile()
    dt = 1e-3
    sim = Simulation(mech, dt)
    with pytest.raises(ConvergenceError) as exc:
        sim.run(t_end=1.0)
    e = exc.value
    assert isinstance(e, SimulationError)
    assert isinstance(e.step, int) and e.step >= 1
    assert e.time == pytest.approx(e.step * dt, abs=1e-12)
    assert e.residual is not None and np.isfinite(e.residual) and e.residual > 0
    assert sim.steps == e.step - 1          # the steps before the failing one were taken
    msg = str(e)
    assert f"step {e.step}" in msg and "Newton" in msg, msg
    # with the default limit the same mechanism runs
    b2, _, _ = pendulum_builder()
    Simulation(b2.compile(), dt).run(t_end=0.1)


# ---- (e) rheonomic drivers ----------------------------------------------------------------------------
def test_constant_speed_crank_driver():
    """theta = 2 t via b.drive(poly=(0, 2)); the tip of a 0.5 m crank follows L (cos 2t, sin 2t) at
    speed 2 L, whatever gravity does."""
    length, omega = 0.5, 2.0
    b = MechanismBuilder(dim=2, name="driven crank")
    o = b.fixed_point((0.0, 0.0), "O")
    p = b.point("P", (length, 0.0))
    theta = b.angle("theta", 0.0)
    b.angle2d(theta, p, o)
    b.rod("crank", o, p, 2.0)
    b.gravity((0.0, -G))
    b.drive(theta, poly=(0.0, omega))
    mech = b.compile()
    assert not mech.conservative
    sim = Simulation(mech, 1e-3)
    traj = sim.run(t_end=5.0, stride=10)
    t = traj.t
    ix, iy, it = (mech.coordinate(n) for n in ("P.x", "P.y", "theta"))
    x, y, vx, vy = traj.q[:, ix], traj.q[:, iy], traj.qd[:, ix], traj.qd[:, iy]
    np.testing.assert_allclose(traj.q[:, it], omega * t, rtol=0, atol=1e-8)
    np.testing.assert_allclose(x, length * np.cos(omega * t), rtol=0, atol=1e-8)
    np.testing.assert_allclose(y, length * np.sin(omega * t), rtol=0, atol=1e-8)
    np.testing.assert_allclose(traj.qd[:, it], omega, rtol=0, atol=1e-6)
    np.testing.assert_allclose(vx, -omega * length * np.sin(omega * t), rtol=0, atol=1e-6)
    np.testing.assert_allclose(vy, omega * length * np.cos(omega * t), rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.hypot(vx, vy), omega * length, rtol=0, atol=1e-6)
    # velocity constraints including Phi_t (at the final time, where the drivers are evaluated)
    phi_max, rate_max = sim.violations(sim.data.q, sim.data.qd)
    assert phi_max <= 1e-8 and rate_max <= 1e-6
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8 and sim.data.stats[ST_MAX_PHID] <= 1e-6


def test_sine_driver_on_point_coordinate():
    """A slider whose x is driven as 0.2 sin(3 t) (a rheonomic linear constraint on a point)."""
    amp, w = 0.2, 3.0
    b = MechanismBuilder(dim=2, name="shaker")
    p = b.point("S", (0.0, 0.0))
    b.point_mass(p, 1.5)
    b.linear([(1.0, p, 1)], name="rail")
    b.drive((p, 0), sine=(0.0, amp, w, 0.0))
    b.gravity((0.0, -G))
    mech = b.compile()
    sim = Simulation(mech, 1e-3)
    traj = sim.run(t_end=3.0, stride=5)
    t = traj.t
    ix, iy = mech.coordinate("S.x"), mech.coordinate("S.y")
    np.testing.assert_allclose(traj.q[:, ix], amp * np.sin(w * t), rtol=0, atol=1e-8)
    np.testing.assert_allclose(traj.qd[:, ix], amp * w * np.cos(w * t), rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.q[:, iy], 0.0, atol=1e-10)


# ---- (f), (g) linear oscillators --------------------------------------------------------------------
def oscillator(m: float, k: float, c: float, x0: float, dt: float, t_end: float):
    """A mass on a prismatic guide along x (y = 0 by a linear constraint), tied to the ground point
    (-1, 0) by a spring-damper of rest length 1: exactly m x'' + c x' + k x = 0, no gravity."""
    b = MechanismBuilder(dim=2, name="oscillator")
    a = b.fixed_point((-1.0, 0.0), "A")
    p = b.point("P", (x0, 0.0))
    b.point_mass(p, m)
    b.linear([(1.0, p, 1)], name="guide")
    b.spring(a, p, k, damping=c, rest_length=1.0)
    mech = b.compile()
    sim = Simulation(mech, dt)
    traj = sim.run(t_end=t_end)
    return mech, sim, traj


def _upward_zero_crossings(t, x):
    i = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def test_undamped_oscillator_period_and_amplitude():
    """The trapezoidal rule on x'' = -w^2 x is the implicit midpoint rule: it rotates the phase
    by exactly 2 atan(w h / 2) per step (so x_n = A cos(w_d t_n), w_d = (2/h) atan(w h/2)) and keeps
    m v^2 + k x^2 exactly. Its period is therefore 2 pi / w_d, longer than 2 pi / w by a relative
    (w h)^2 / 12 (2.1e-6 here), and the phase error grows as w t (w h)^2 / 12."""
    m, k, amp, dt, t_end = 2.0, 50.0, 0.1, 1e-3, 10.0
    mech, sim, traj = oscillator(m, k, 0.0, amp, dt, t_end)
    assert mech.conservative
    t, x, v = traj.t, traj.q[:, mech.coordinate("P.x")], traj.qd[:, mech.coordinate("P.x")]
    w = np.sqrt(k / m)
    wd = 2.0 / dt * np.arctan(w * dt / 2.0)
    lag = (w * dt) ** 2 / 12.0
    # the exact discrete solution of the trapezoidal rule
    np.testing.assert_allclose(x, amp * np.cos(wd * t), rtol=0, atol=1e-9 * amp)
    # the continuous solution, within the phase-error bound
    assert np.max(np.abs(x - amp * np.cos(w * t))) <= 1.1 * amp * w * t_end * lag
    # period from the zero crossings: 2 pi / w_d, i.e. 2 pi / w (1 + (w h)^2 / 12)
    periods = np.diff(_upward_zero_crossings(t, x))
    assert len(periods) >= 5
    np.testing.assert_allclose(periods, 2 * np.pi / wd, rtol=1e-8)
    rel = periods.mean() / (2 * np.pi / w) - 1.0
    assert rel == pytest.approx(lag, rel=0.02)
    # amplitude (energy) preserved to the solver tolerances
    e = 0.5 * m * v ** 2 + 0.5 * k * x ** 2
    np.testing.assert_allclose(e, 0.5 * k * amp ** 2, rtol=1e-9)
    np.testing.assert_allclose(sim.energy(traj), 0.5 * k * amp ** 2, rtol=1e-9)
    np.testing.assert_allclose(traj.q[:, mech.coordinate("P.y")], 0.0, atol=1e-12)


def test_damped_oscillator_decay_rate():
    """m x'' + c x' + k x = 0 from (A, 0): x = A e^(-s t) (cos w_d t + s / w_d sin w_d t),
    s = c / (2 m). Successive peaks decay exactly as e^(-s t)."""
    m, k, c, amp, dt, t_end = 1.0, 100.0, 1.0, 0.1, 1e-3, 5.0
    mech, sim, traj = oscillator(m, k, c, amp, dt, t_end)
    assert not mech.conservative
    t, x = traj.t, traj.q[:, mech.coordinate("P.x")]
    s = c / (2 * m)
    w = np.sqrt(k / m)
    wdd = np.sqrt(w ** 2 - s ** 2)
    exact = amp * np.exp(-s * t) * (np.cos(wdd * t) + s / wdd * np.sin(wdd * t))
    # phase error of the trapezoidal rule w t (w h)^2 / 12 on an amplitude A e^(-s t):
    # at most A w (w h)^2 / 12 max_t(t e^(-s t)) = A w (w h)^2 / (12 e s); 2x margin
    bound = 2.0 * amp * w * (w * dt) ** 2 / (12.0 * np.e * s)
    assert np.max(np.abs(x - exact)) <= bound
    # peaks (parabolic interpolation through the sampled maxima)
    j = np.nonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:]))[0] + 1
    assert len(j) >= 6
    ym, y0, yp = x[j - 1], x[j], x[j + 1]
    off = 0.5 * (ym - yp) / (ym - 2 * y0 + yp)
    peaks = y0 - 0.25 * (ym - yp) * off
    tp = t[j] + off * dt
    rate = -np.polyfit(tp, np.log(peaks), 1)[0]
    assert rate == pytest.approx(s, rel=1e-3)


# ---- (h) redundant constraints --------------------------------------------------------------------
def _pendulum_with(extra: str | None):
    b, o, p = pendulum_builder()
    if extra == "same":          # the same constraint, declared again under another name
        b.dot((o, p), (o, p), name="distance again")
    elif extra == "reversed":    # the same equation written (P - O).(P - O): a duplicate row
        b.dot((p, o), (p, o), name="reversed distance")
    return b.compile()


@pytest.mark.parametrize("extra", ["same", "reversed"])
def test_duplicate_constraint_gives_same_trajectory(extra):
    once = _pendulum_with(None)
    twice = _pendulum_with(extra)
    t1 = Simulation(once, 1e-3).run(t_end=5.0, stride=10)
    sim2 = Simulation(twice, 1e-3)
    t2 = sim2.run(t_end=5.0, stride=10)
    np.testing.assert_allclose(t2.q, t1.q, rtol=0, atol=1e-8)
    np.testing.assert_allclose(t2.qd, t1.qd, rtol=0, atol=1e-7)
    assert sim2.data.stats[ST_MAX_PHI] <= 1e-8 and sim2.data.stats[ST_MAX_PHID] <= 1e-6
    ref = R.pendulum_reference(t2.t)
    assert np.max(np.abs(t2.q[:, twice.coordinate("P1.x")] - ref["x_P1"])) <= 1e-3


def test_genuinely_redundant_parallelogram():
    """Three parallel 1 m cranks (1 kg rods) pivoted at (0,0), (1,0), (2,0) carrying ONE rigid
    2 m, 2 kg coupler through B0, B1, B2: 6 coordinates, 6 constraints, yet one degree of freedom
    (the Jacobian has rank 5). Its dynamics are exactly the N = 2 four-bar's: the generalized mass
    m L^2 (3/3 + 2) and potential m g L (3/2 + 2) sin(theta) are the same."""
    b = MechanismBuilder(dim=2, name="parallelogram")
    tips = []
    for i in range(3):
        a = b.fixed_point((float(i), 0.0), f"A{i}")
        tip = b.point(f"B{i}", (float(i), 1.0), velocity=(1.0, None) if i == 0 else None)
        b.rod(f"crank{i}", a, tip, 1.0)
        tips.append(tip)
    b.rod("coupler", tips[0], tips[2], 2.0)
    b.body_point("coupler", tips[0], [(tips[2], tips[0])], tips[1])
    b.gravity((0.0, -G))
    mech = b.compile()
    sim = Simulation(mech, 1e-3)
    _, jac = sim.constraint_jacobian(sim.data.q)
    assert jac.shape == (6, 6)
    assert np.linalg.matrix_rank(jac) == 5        # the premise: one redundant constraint
    traj = sim.run(t_end=10.0, stride=10)
    ref = R.fourbar_reference(2, traj.t)
    for c in "xy":
        err = np.max(np.abs(traj.q[:, mech.coordinate(f"B0.{c}")] - ref[f"{c}_B0"]))
        assert err <= 1e-3, (c, err)
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8
    assert sim.data.stats[ST_MAX_PHID] <= 1e-6
    # the crank tips stay 1 m apart along the coupler and the coupler stays horizontal-parallel
    b0, b1, b2 = (traj.q[:, [mech.coordinate(f"B{i}.x"), mech.coordinate(f"B{i}.y")]] for i in range(3))
    np.testing.assert_allclose(b1 - b0, np.tile([1.0, 0.0], (len(traj.t), 1)), atol=1e-8)
    np.testing.assert_allclose(b2 - b1, np.tile([1.0, 0.0], (len(traj.t), 1)), atol=1e-8)
