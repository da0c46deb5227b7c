"""Whole scenarios through the vehicle model: the seed's straight-line manoeuvre on the surveyed
campus track (its published distance and peak speed), and the stop at its end (no creep, no
oscillation at standstill)."""
import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.vehicle.offline import prepare, run, write_csv, COLUMNS

SEED_DISTANCE = 63.5      # m, xbw-vehicle-mbs-validation sec. 2.3
SEED_PEAK_SPEED = 23 / 3.6  # m/s


@pytest.fixture(scope="module")
def straight_line():
    sim, sc = prepare(None, load_scenario("configs/scenarios/straight_line.toml", check_files=True))
    return run(sim, sc), sim


def test_straight_line_matches_the_seed_figures(straight_line):
    res, _ = straight_line
    x, y = res.column("pos_x"), res.column("pos_y")
    distance = float(np.sum(np.hypot(np.diff(x), np.diff(y))))
    assert abs(distance - SEED_DISTANCE) <= 0.05 * SEED_DISTANCE
    assert abs(res.column("speed").max() - SEED_PEAK_SPEED) <= 0.05 * SEED_PEAK_SPEED
    assert np.max(np.abs(y)) < 0.05                       # straight ahead on a surveyed, crowned lane


def test_straight_line_stops_without_creep_or_oscillation(straight_line):
    res, _ = straight_line
    t, x, v = res.column("time"), res.column("pos_x"), res.column("speed")
    stopped = np.nonzero((t > 15.0) & (v < 1e-3))[0]
    assert stopped.size, "the car never stopped"
    i0 = stopped[0]
    assert t[-1] - t[i0] > 5.0                            # at least 5 s of standstill observed
    # after the stop the body rocks back on its suspension and tyres (a few mm, damped within a
    # second); from then on nothing may move: no creep, no oscillation
    settled = t >= t[i0] + 1.0
    assert np.ptp(x[settled]) < 1e-3
    assert np.max(v[t >= t[-1] - 5.0]) < 1e-4
    assert np.max(res.column("constraint_violation")) <= 1e-8


def test_csv_has_the_channel_columns(straight_line, tmp_path):
    res, _ = straight_line
    out = tmp_path / "run.csv"
    write_csv(res, out)
    header = out.read_text().splitlines()[0].split(",")
    assert tuple(header) == COLUMNS
    for name in ("time", "accel_x", "wheel_angle_rr", "brake_pressure", "pos_x", "tyre_fz_rr", "constraint_violation"):
        assert name in header


def test_mcap_output_round_trips(straight_line, tmp_path):
    """The MCAP file holds one sensors and one state message per logged row, with the same values."""
    from bridge.mcap_log import read_messages, write_run
    res, sim = straight_line
    out = tmp_path / "run.mcap"
    rows = res.data[:200]
    write_run(out, res.columns, rows, sim.vm.config.id, sim.vm.channels)
    msgs = list(read_messages(out, f"rtsim/{sim.vm.config.id}/sensors"))
    assert len(msgs) == len(rows)
    for (t, m), r in zip(msgs, rows):
        assert abs(t - r[0]) < 1e-9
        assert m["brake_pressure"] == r[res.columns.index("brake_pressure")]
    state = list(read_messages(out, f"rtsim/{sim.vm.config.id}/state"))
    assert len(state) == len(rows) and "tyre_fz_rr" in state[0][1]


def test_sensor_model_bias_quantisation_delay_and_noise(tmp_path):
    """The vehicle config's sensor model on logged samples: a bias shifts, a quantum rounds, a delay
    shifts by whole samples, white noise has the configured standard deviation; all against the same
    run without it."""
    import shutil
    import tomllib
    src = "configs/vehicles/xbw.toml"
    text = open(src).read()
    extra = """
[sensors.channels.accel_x]
bias = 0.5
[sensors.channels.brake_pressure]
quantum = 100.0
[sensors.channels.engine_speed]
delay_s = 0.01
[sensors.channels.gyro_z]
noise_std = 0.01
"""
    vfile = tmp_path / "xbw.toml"
    vfile.write_text(text.replace('[tyres]\nproperty_file = "../tyres/', f'[tyres]\nproperty_file = "{(tmp_path / "tyres").as_posix()}/') + extra)
    shutil.copytree("configs/tyres", tmp_path / "tyres")
    assert tomllib.loads(vfile.read_text())["sensors"]["channels"]["accel_x"]["bias"] == 0.5
    base_sim, sc = prepare(None, load_scenario("configs/scenarios/step_steer_80kph.toml", check_files=True))
    base = run(base_sim, sc)
    sim, sc = prepare(vfile, load_scenario("configs/scenarios/step_steer_80kph.toml", check_files=True))
    res = run(sim, sc, seed=1)
    c = res.columns.index
    assert np.allclose(res.data[:, c("accel_x")], base.data[:, c("accel_x")] + 0.5, atol=1e-9)
    bp = res.data[:, c("brake_pressure")]
    assert np.allclose(bp, 100.0 * np.round(base.data[:, c("brake_pressure")] / 100.0))
    lag = round(0.01 * sc.spec.output_rate)
    assert np.allclose(res.data[lag:, c("engine_speed")], base.data[:-lag, c("engine_speed")])
    noise = res.data[:, c("gyro_z")] - base.data[:, c("gyro_z")]
    assert 0.008 < np.std(noise) < 0.012 and abs(np.mean(noise)) < 0.002


@pytest.mark.parametrize("vehicle", [None, "configs/vehicles/xbw_fwd.toml"], ids=["xbw", "xbw_fwd"])
@pytest.mark.parametrize("scenario", ["straight_line", "step_steer_80kph", "step_steer_braking_80kph",
                                      "steady_circle"])
def test_every_scenario_runs_within_the_constraint_bar(scenario, vehicle):
    """Each shipped scenario runs to its end (no convergence error) with |Phi| <= 1e-8 and
    |Phi_q qd + Phi_t| <= 1e-6 after every step, on the prototype and on its second assembly from the
    same kit (front-wheel drive, vertical sliders: a config file only)."""
    from rtsim.mbs.model import ST_MAX_PHI, ST_MAX_PHID, ST_STEPS
    sim, sc = prepare(vehicle, load_scenario(f"configs/scenarios/{scenario}.toml", check_files=True))
    res = run(sim, sc)
    st = sim.data.stats
    assert st[ST_STEPS] == round(sc.duration / sc.dt)
    assert st[ST_MAX_PHI] <= 1e-8 and st[ST_MAX_PHID] <= 1e-6
    assert np.all(np.isfinite(res.data))
