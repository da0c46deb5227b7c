"""Steering feel, measured: the steering-wheel torque against the lateral acceleration of a recorded run
(an on-centre weave, a slow ramp steer) and what the power-steering motor spent on it.

Channels (a run of `rtsim run`, CSV or MCAP, read by bridge.run_files.read_recorded):

    accel_y               m/s^2  the lateral accelerometer (body frame, at the IMU: what a test's
                                 measuring unit reads; shown in g, 1 g = 9.81 m/s^2)
    driver_torque         N m    the steering-wheel torque: the torque the driver's hands put on the rim
    steering_wheel_angle  rad    the steering-wheel angle (shown in deg)
    motor_current, motor_voltage, motor_power (A, V, W: V i) and the power audit's cumulative
    work_motor_supply, work_motor_winding, stored_inductance (J): the EPS motor

Why `driver_torque` and not `torsion_bar_torque`: feel is the torque at the rim, which is what an
on-centre test's measuring steering wheel records. In angle mode the driver imposes the wheel's angle and
`driver_torque` is the constraint's reaction, the torque needed to move the wheel along that path: the
torsion bar's torque plus the column's friction and the wheel's inertia. The torsion-bar torque is the
torque sensor's reading, the assist law's input, and lacks those two (at 0.2 Hz they are a few
hundredths of a N m, so the two nearly agree; in a fast manoeuvre they do not). In torque mode
`driver_torque` is the torque applied. Both modes: the same channel, the same meaning.

What is measured (`steering_feel`), over the steady part of the run (`steady_window`: the complete
cycles of the steering-wheel angle at >= 95 % of the largest amplitude; the whole run if it has fewer
than two cycles, e.g. a ramp):

- Branches. A sample is on the rising branch while the steering-wheel angle increases, on the falling
  one while it decreases (the input's direction: smooth, and free of the lateral acceleration's lag);
  samples where the angle is still (|rate| < 2 % of its largest) belong to neither.
- Torque gradient at a (N m/g): on each branch a least-squares straight line of the torque against
  the lateral acceleration over the samples within a +- half-width (default 0.02 g) of a; for a > 0
  the same at -a (the loop's mirror image); the mean of the slopes found. At 0 g the gradient of the
  on-centre region, at 0.1 g the issue's bar.
- Hysteresis. Torque width at 0 g: the mean torque where the lateral acceleration crosses 0 upwards
  less the mean where it crosses downwards (N m); lateral-acceleration width at 0 N m: the mean
  lateral acceleration where the torque crosses 0 downwards less the mean where it crosses upwards
  (g). Both positive for the usual loop, the torque leading the lateral acceleration. Crossings are
  counted with a dead band (5 % of the largest value) so that noise about 0 does not count; without a
  crossing in each direction (a ramp) there is no hysteresis (None).
- Steering-wheel angle gradient (deg/g): as the torque gradient, the angle in place of the torque.
- Motor: peak |current| (A), RMS current (A), peak |voltage| (V), electrical power V i (W): its
  largest magnitude (signed) and its time mean; mechanical power (W): the power the motor converts,
  Kt i w_m = supply - winding loss - d(inductance energy)/dt, from the audit's cumulative energies
  (interval means between recorded rows), its largest magnitude (signed: negative when back-driven).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from rtsim.errors import ConfigError

from .figures import G

TORQUE = "driver_torque"
REQUIRED = ("time", "accel_y", "steering_wheel_angle", TORQUE)
HALF_WIDTH = 0.02          # g, half-width of the window of a local fit
MIN_POINTS = 5             # samples a local fit needs
STILL = 0.02               # share of the largest angle rate below which the angle is still
DEAD_BAND = 0.05           # share of the largest |value| a crossing must pass through
STEADY = 0.95              # share of the largest cycle amplitude a steady cycle has
ANGLE_FLOOR = 1e-4         # rad (0.006 deg): a steering-wheel angle that varies less has no cycles


# --------------------------------------------------------------------------------------------- parts
def branches(t: np.ndarray, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the rising (angle increasing) and falling branches; still samples in neither."""
    rate = np.gradient(angle, t) if len(t) > 1 else np.zeros_like(angle)
    lim = STILL * float(np.max(np.abs(rate), initial=0.0))
    return rate > lim, rate < -lim


def local_slope(x: np.ndarray, y: np.ndarray, mask: np.ndarray, x0: float,
                half_width: float = HALF_WIDTH) -> float:
    """Slope dy/dx of a least-squares line through the masked samples with |x - x0| <= half_width;
    NaN with fewer than MIN_POINTS of them or no spread in x."""
    sel = mask & (np.abs(x - x0) <= half_width)
    if np.count_nonzero(sel) < MIN_POINTS:
        return math.nan
    xs, ys = x[sel] - x0, y[sel]
    xc = xs - xs.mean()
    den = float(np.dot(xc, xc))
    return float(np.dot(xc, ys - ys.mean()) / den) if den > 0.0 else math.nan


def gradient(x: np.ndarray, y: np.ndarray, rising: np.ndarray, falling: np.ndarray, at: float,
             half_width: float = HALF_WIDTH) -> tuple[float, dict[str, float]]:
    """The mean of the branches' local slopes at x = at (and at -at if at > 0), and each slope found,
    keyed like 'rising@+0.1'."""
    found = {}
    for x0 in ((at, -at) if at > 0.0 else (at,)):
        for name, mask in (("rising", rising), ("falling", falling)):
            s = local_slope(x, y, mask, x0, half_width)
            if math.isfinite(s):
                found[f"{name}@{x0:+g}"] = s
    return (float(np.mean(list(found.values()))) if found else math.nan), found


def crossings(x: np.ndarray, y: np.ndarray, dead_band: float = DEAD_BAND) -> tuple[list[float], list[float]]:
    """The values of y where x crosses 0 upwards and downwards (linear interpolation between samples).
    A crossing counts once x has gone from beyond -b to beyond +b (or back), b = dead_band * max|x|;
    of several zero crossings within one passage the last is taken."""
    b = dead_band * float(np.max(np.abs(x), initial=0.0))
    up: list[float] = []
    down: list[float] = []
    side = 0                       # -1: last beyond -b, +1: beyond +b
    last = -1                      # index i of the latest zero crossing between i and i + 1
    for i in range(len(x)):
        if i > 0 and (x[i - 1] < 0.0) != (x[i] < 0.0):
            last = i - 1
        s = 1 if x[i] > b else (-1 if x[i] < -b else 0)
        if s and s != side:
            if side and last >= 0:
                f = -x[last] / (x[last + 1] - x[last])
                (up if s > 0 else down).append(float(y[last] + f * (y[last + 1] - y[last])))
            side = s
    return up, down


def hysteresis(x: np.ndarray, y: np.ndarray) -> float | None:
    """Mean y at the upward zero crossings of x less the mean at the downward ones (None without a
    crossing either way)."""
    up, down = crossings(x, y)
    return float(np.mean(up) - np.mean(down)) if up and down else None


def steady_window(t: np.ndarray, angle: np.ndarray) -> tuple[float, float]:
    """(start, end): from the first to the last complete cycle of the angle (between upward crossings of
    its mid-range, with the dead band) whose amplitude is >= STEADY of the largest; the whole run with
    fewer than two cycles, or an angle whose range is below ANGLE_FLOOR (a run held straight: its angle
    varies by round-off, whose crossings are no cycles)."""
    if len(angle) == 0 or float(np.ptp(angle)) < ANGLE_FLOOR:
        return (float(t[0]), float(t[-1])) if len(t) else (0.0, 0.0)
    mid = 0.5 * (angle.max() + angle.min())
    ups = _up_indices(angle - mid)
    if len(ups) < 2:
        return float(t[0]), float(t[-1])
    amps = [0.5 * float(np.ptp(angle[a:b + 1])) for a, b in zip(ups, ups[1:])]
    keep = [k for k, a in enumerate(amps) if a >= STEADY * max(amps)]
    return float(t[ups[keep[0]]]), float(t[ups[keep[-1] + 1]])


def _up_indices(x: np.ndarray) -> list[int]:
    """Sample indices of the counted upward zero crossings of x (as `crossings`)."""
    idx = np.arange(len(x), dtype=float)
    up, _down = crossings(x, idx)
    return [int(math.ceil(i)) for i in up]


# ------------------------------------------------------------------------------------------ the report
@dataclass
class Feel:
    """The steering feel of a run (units in the names; None / NaN where the run does not show it)."""
    window_s: tuple[float, float]
    at_g: float                                   # the second gradient's lateral acceleration
    ay_peak_g: float                              # largest |lateral acceleration| in the window
    torque_peak_nm: float
    torque_gradient_0g: float                     # N m/g
    torque_gradient_at: float                     # N m/g at +-at_g
    torque_hysteresis_nm: float | None            # torque width at 0 g
    ay_hysteresis_g: float | None                 # lateral-acceleration width at 0 N m
    angle_gradient_0g: float                      # deg/g
    angle_gradient_at: float                      # deg/g at +-at_g
    current_peak_a: float | None = None
    current_rms_a: float | None = None
    voltage_peak_v: float | None = None
    power_peak_w: float | None = None             # electrical, V i
    power_mean_w: float | None = None
    mech_power_peak_w: float | None = None        # converted, Kt i w_m
    branches: dict[str, dict[str, float]] = field(default_factory=dict)   # each local slope found

    def as_dict(self) -> dict:
        """Plain values for JSON (NaN as None)."""
        def clean(v):
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (tuple, list)):
                return [clean(x) for x in v]
            return None if isinstance(v, float) and not math.isfinite(v) else v
        return clean(asdict(self))


def steering_feel(columns, data, start: float | None = None, end: float | None = None, at: float = 0.1,
                  half_width: float = HALF_WIDTH, source: str = "run") -> Feel:
    """The feel of a recorded run (`columns`, `data` as read_recorded returns them) between `start` and
    `end` (s; default: the steady window). `at`: the second gradient's lateral acceleration (g)."""
    col = {c: np.asarray(data, dtype=float)[:, i] for i, c in enumerate(columns)}
    missing = [c for c in REQUIRED if c not in col]
    if missing:
        raise ConfigError(f"{source}: no {', '.join(missing)} channel; the feel needs a run of a car with "
                          f"electric power steering recorded with its power audit (rtsim run)")
    t = col["time"]
    ok = np.all(np.isfinite(np.column_stack([col[c] for c in REQUIRED])), axis=1)
    if not np.any(col[TORQUE][ok] != 0.0):
        raise ConfigError(f"{source}: {TORQUE} is zero throughout: not a run of a car with electric power steering")
    w0, w1 = steady_window(t[ok], col["steering_wheel_angle"][ok])
    w0 = w0 if start is None else start
    w1 = w1 if end is None else end
    sel = ok & (t >= w0) & (t <= w1)
    if np.count_nonzero(sel) < 2 * MIN_POINTS:
        raise ConfigError(f"{source}: only {np.count_nonzero(sel)} samples between {w0:g} and {w1:g} s")
    tt = t[sel]
    ay = col["accel_y"][sel] / G
    trq = col[TORQUE][sel]
    ang = np.degrees(col["steering_wheel_angle"][sel])
    up, down = branches(tt, ang)
    g0, b_t0 = gradient(ay, trq, up, down, 0.0, half_width)
    ga, b_ta = gradient(ay, trq, up, down, at, half_width)
    a0, b_a0 = gradient(ay, ang, up, down, 0.0, half_width)
    aa, b_aa = gradient(ay, ang, up, down, at, half_width)
    ay_w = hysteresis(trq, ay)
    feel = Feel((float(tt[0]), float(tt[-1])), at, float(np.max(np.abs(ay))), float(np.max(np.abs(trq))),
                g0, ga, hysteresis(ay, trq), None if ay_w is None else -ay_w, a0, aa,
                branches={"torque@0": b_t0, f"torque@{at:g}": b_ta, "angle@0": b_a0, f"angle@{at:g}": b_aa})
    _motor(feel, col, sel)
    return feel


def _motor(feel: Feel, col: dict[str, np.ndarray], sel: np.ndarray) -> None:
    """The motor's figures into `feel` (left None for channels the run lacks)."""
    t = col["time"][sel]
    span = float(t[-1] - t[0])

    def mean(v):
        return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)) / span) if span > 0.0 else float(v[0])
    if "motor_current" in col:
        i = col["motor_current"][sel]
        feel.current_peak_a = float(np.max(np.abs(i)))
        feel.current_rms_a = math.sqrt(mean(i * i))
    if "motor_voltage" in col:
        feel.voltage_peak_v = float(np.max(np.abs(col["motor_voltage"][sel])))
    if "motor_power" in col:
        p = col["motor_power"][sel]
        feel.power_peak_w = float(p[np.argmax(np.abs(p))])
        feel.power_mean_w = mean(p)
    p_mech = mechanical_power(col, sel)
    if p_mech is not None and p_mech.size:
        feel.mech_power_peak_w = float(p_mech[np.argmax(np.abs(p_mech))])


def mechanical_power(col: dict[str, np.ndarray], sel: np.ndarray | None = None) -> np.ndarray | None:
    """The power the motor converts (W), Kt i w_m, between consecutive rows: the interval means of
    d/dt (supply - winding loss - inductance energy) from the audit's cumulative energies; None without
    them."""
    names = ("work_motor_supply", "work_motor_winding", "stored_inductance")
    if not all(n in col for n in names):
        return None
    sel = np.ones(len(col["time"]), dtype=bool) if sel is None else sel
    e = col["work_motor_supply"][sel] + col["work_motor_winding"][sel] - col["stored_inductance"][sel]
    return np.diff(e) / np.maximum(np.diff(col["time"][sel]), 1e-12)


# ------------------------------------------------------------------------------------------- printing
ROWS = (   # (label, attribute, unit, format)
    ("analysed window", "window_s", "s", None),
    ("peak lateral acceleration", "ay_peak_g", "g", ".3f"),
    ("peak steering-wheel torque", "torque_peak_nm", "N m", ".2f"),
    ("torque gradient at 0 g", "torque_gradient_0g", "N m/g", ".1f"),
    ("torque gradient at {at} g", "torque_gradient_at", "N m/g", ".1f"),
    ("torque hysteresis at 0 g", "torque_hysteresis_nm", "N m", ".2f"),
    ("lateral-acc. hysteresis at 0 N m", "ay_hysteresis_g", "g", ".3f"),
    ("steering-wheel angle gradient at 0 g", "angle_gradient_0g", "deg/g", ".1f"),
    ("steering-wheel angle gradient at {at} g", "angle_gradient_at", "deg/g", ".1f"),
    ("motor current, peak", "current_peak_a", "A", ".2f"),
    ("motor current, RMS", "current_rms_a", "A", ".2f"),
    ("motor voltage, peak", "voltage_peak_v", "V", ".2f"),
    ("electrical power V i, peak", "power_peak_w", "W", ".2f"),
    ("electrical power V i, mean", "power_mean_w", "W", ".3f"),
    ("mechanical power Kt i w, peak", "mech_power_peak_w", "W", ".2f"),
)


def rows(feel: Feel) -> list[tuple[str, str, str]]:
    """(quantity, value, unit) of the report, '-' where the run does not show it."""
    out = []
    for label, attr, unit, fmt in ROWS:
        v = getattr(feel, attr)
        if attr == "window_s":
            text = f"{v[0]:.2f} .. {v[1]:.2f}"
        elif v is None or (isinstance(v, float) and not math.isfinite(v)):
            text = "-"
        else:
            text = format(v, fmt)
        out.append((label.format(at=f"{feel.at_g:g}"), text, unit))
    return out


def table(feel: Feel, title: str):
    """The report as a rich Table."""
    from rich.table import Table

    tab = Table(title=f"steering feel: {title}", title_justify="left")
    tab.add_column("quantity")
    tab.add_column("value", justify="right")
    tab.add_column("unit")
    for r in rows(feel):
        tab.add_row(*r)
    return tab
