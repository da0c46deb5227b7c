"""Figures of a run (rtsim.analyses.figures): from an offline run, from its CSV and MCAP files, and through
`rtsim run --plot` and `rtsim plot`; PNG files for the channels a run has, none for those it lacks."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.mcap_log import read_run, write_run
from drivers.scenario import load_scenario
from bridge.run_files import read_recorded
from rtsim.analyses.figures import default_dir, write_run_figures
from rtsim.cli import main
from rtsim.errors import ConfigError
from rtsim.vehicle.offline import prepare, run, write_csv

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
DURATION = 1.5          # s: past the steering step at 1 s
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MIN_BYTES = 5000        # a drawn figure, not an empty canvas
ALL = ("lateral_acceleration.png", "tyre_vertical_forces.png", "steering.png")


def _assert_pngs(paths, names):
    assert [p.name for p in paths] == list(names)
    for p in paths:
        head = p.read_bytes()[:8]
        assert head == PNG_MAGIC, (p, head)
        assert p.stat().st_size > MIN_BYTES, (p, p.stat().st_size)


@pytest.fixture(scope="module")
def short_run():
    sc = load_scenario(SCENARIO, check_files=True)
    sc.spec = sc.spec.model_copy(update={"duration": DURATION})
    sim, sc = prepare(None, sc)
    res = run(sim, sc)
    assert res.data[-1, 0] == pytest.approx(DURATION)
    return res, sim


def _short_scenario(folder: Path) -> Path:
    """The step steer cut to DURATION, in `folder`, its road by absolute path."""
    text = SCENARIO.read_text()
    road = (ROOT / "configs" / "roads" / "flat.toml").as_posix()
    assert 'road = "../roads/flat.toml"' in text and "duration = 6.0" in text
    text = text.replace('road = "../roads/flat.toml"', f'road = "{road}"')
    text = text.replace("duration = 6.0", f"duration = {DURATION}")
    path = folder / "short_step_steer.toml"
    path.write_text(text)
    return path


def test_run_figures_are_pngs(short_run, tmp_path):
    res, _ = short_run
    for name in ("accel_y", "steering_wheel_angle", "steering_torque", "tyre_fz_fl", "tyre_fz_rr"):
        assert name in res.columns
    out = tmp_path / "figs"
    paths = write_run_figures(res.columns, res.data, out, "step steer")
    _assert_pngs(paths, ALL)
    assert all(p.parent == out for p in paths)


def test_missing_columns_skip_their_figures(short_run, tmp_path):
    res, _ = short_run
    keep = ("time", "accel_y", "steering_torque")
    cols = [res.columns.index(c) for c in keep]
    paths = write_run_figures(keep, res.data[:, cols], tmp_path / "some", "subset")
    _assert_pngs(paths, ("lateral_acceleration.png", "steering.png"))
    keep = ("time", "tyre_fz_rl")
    paths = write_run_figures(keep, res.data[:, [res.columns.index(c) for c in keep]], tmp_path / "one", "one")
    _assert_pngs(paths, ("tyre_vertical_forces.png",))
    assert write_run_figures(("time", "speed"), res.data[:, :2], tmp_path / "none", "none") == []
    assert not (tmp_path / "none").exists()
    with pytest.raises(ConfigError, match="no time column"):
        write_run_figures(("accel_y",), res.data[:, :1], tmp_path / "x", "no time")


def test_recordings_read_back_as_the_run(short_run, tmp_path):
    """CSV and MCAP of a run read back with its columns and values (CSV: 9 significant digits)."""
    res, sim = short_run
    csv_path, mcap_path = tmp_path / "r.csv", tmp_path / "r.mcap"
    write_csv(res, csv_path)
    write_run(mcap_path, res.columns, res.data, sim.vm.config.id, sim.vm.channels)
    for path, rtol in ((csv_path, 1e-8), (mcap_path, 0.0)):
        cols, data = read_recorded(path)
        assert cols == res.columns
        np.testing.assert_allclose(data, res.data, rtol=rtol, atol=1e-300)
    with pytest.raises(ConfigError, match="unknown run format"):
        read_recorded(tmp_path / "r.txt")


def test_mcap_state_at_other_times_is_interpolated(tmp_path):
    """A recording whose state messages come at other times than its sensor messages: one table at the
    sensor times, the state interpolated onto them, NaN outside the state's time span."""
    from bridge.mcap_recorder import Recorder
    from bridge.payloads import encode_json
    path = tmp_path / "session.mcap"
    with Recorder(path, "xbw") as rec:
        for k in range(11):
            t = 0.01 * k
            rec.record("sensors", round(t * 1e9), encode_json({"time": t, "accel_y": 9.81 * k}))
        for k in range(5):
            t = 0.02 * k + 0.01
            rec.record("state", round(t * 1e9), encode_json({"time": t, "tyre_fz_fl": 1000.0 * t}))
    cols, data = read_run(path)
    assert cols == ("time", "accel_y", "tyre_fz_fl")
    np.testing.assert_allclose(data[:, 0], 0.01 * np.arange(11))
    np.testing.assert_allclose(data[:, 1], 9.81 * np.arange(11))
    fz = data[:, 2]
    assert np.isnan(fz[0]) and np.isnan(fz[10])
    np.testing.assert_allclose(fz[1:10], 1000.0 * data[1:10, 0])


def test_cli_run_plot_default_and_given_dir(tmp_path, capsys):
    scenario = _short_scenario(tmp_path)
    out = tmp_path / "run.csv"
    assert main(["run", "--scenario", str(scenario), "--out", str(out), "--plot"]) == 0
    printed = capsys.readouterr().out
    folder = tmp_path / "run_plots"
    assert default_dir(out) == folder
    _assert_pngs([folder / n for n in ALL], ALL)
    for n in ALL:
        assert str(folder / n) in printed
    given = tmp_path / "given"
    assert main(["run", "--scenario", str(scenario), "--out", str(tmp_path / "run.mcap"), "--plot", str(given)]) == 0
    _assert_pngs([given / n for n in ALL], ALL)
    assert sorted(p.name for p in given.iterdir()) == sorted(ALL)


def test_cli_plot_reads_recordings(short_run, tmp_path, capsys):
    res, sim = short_run
    mcap_path, csv_path = tmp_path / "rec.mcap", tmp_path / "rec.csv"
    write_run(mcap_path, res.columns, res.data, sim.vm.config.id, sim.vm.channels)
    write_csv(res, csv_path)
    assert main(["plot", str(mcap_path)]) == 0
    _assert_pngs([tmp_path / "rec_plots" / n for n in ALL], ALL)
    assert main(["plot", str(csv_path), "--out", str(tmp_path / "from_csv")]) == 0
    _assert_pngs([tmp_path / "from_csv" / n for n in ALL], ALL)
    assert str(tmp_path / "from_csv" / "steering.png") in capsys.readouterr().out
    assert main(["plot", str(tmp_path / "rec.txt")]) == 2
    assert main(["plot", str(tmp_path / "missing.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("rtsim: error:") == 2 and "Traceback" not in err
