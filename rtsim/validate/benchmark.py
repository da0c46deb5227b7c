"""The benchmark data (the seed's first phase): the repetitions checked, aligned, resampled to one
grid, and reduced per channel to the sample mean and its 95 % confidence band (stats.band).

Which runs are left out, and why (each reason is reported):
- a run without an input channel that most runs have (it cannot be a repetition of the same test);
- a run whose inputs are not a repetition: Pearson correlation of its aligned inputs with the
  reference run below `MIN_CORRELATION`, or an RMS deviation from the other runs' median inputs above
  `MAX_INPUT_DEVIATION` of the input's range (and several times the typical deviation);
- a run that covers less than `MIN_COVERAGE` of the manoeuvre the others cover.
Two runs that disagree cannot say which is the odd one: that is an error. One run gives a comparison
without a band (said so in the notes and the report).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rtsim.channels import SENSOR_NAMES
from rtsim.errors import ConfigError

from .align import Alignment, align, default_profile, varying_inputs
from .data import Rejected, Run
from .signals import DERIVED, WHEEL_SPEEDS, derive_wheel_speeds, resample
from .stats import Band, band

MIN_CORRELATION = 0.9
MAX_INPUT_DEVIATION = 0.15
MIN_COVERAGE = 0.8
DEFAULT_RATE = 100.0          # Hz, the comparison grid
LONGITUDINAL = (*WHEEL_SPEEDS, "accel_x")
LATERAL = ("accel_y", "gyro_z", "roll")


@dataclass
class Benchmark:
    t: np.ndarray                         # grid, s (0 = start of the common window)
    dt: float                             # grid step, s
    runs: list[Run]                       # the runs used
    rejected: list[Rejected]              # the runs left out, with the reason
    alignment: Alignment                  # offsets are the run times at grid t = 0
    values: dict[str, np.ndarray]         # channel -> (k, n_t) values of the runs that carry it
    bands: dict[str, Band]                # channel -> mean and 95 % band (inputs and outputs)
    inputs: list[str]                     # input channels present in every used run
    compared: list[str]                   # output channels compared with the model
    repeatability: dict[str, dict]        # per input: spread of the runs
    lateral: bool                         # steering manoeuvre (lateral channels compared)
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.runs)

    def mean(self, channel: str) -> np.ndarray:
        return self.bands[channel].mean


def _majority_inputs(runs: list[Run], rejected: list[Rejected], profile) -> list[Run]:
    keep = list(runs)
    for name in profile.inputs:
        have = [r for r in keep if name in r.channels]
        if 0 < len(have) < len(keep) and len(have) > len(keep) / 2:
            for r in keep:
                if name not in r.channels:
                    rejected.append(Rejected(r.path, f"missing input channel {name} that {len(have)} of "
                                                     f"{len(keep)} runs have: not a repetition of the same test"))
            keep = have
    return keep


def _input_deviation(runs: list[Run], al: Alignment, names: list[str]) -> tuple[np.ndarray, list[str]]:
    """Per run: the largest RMS deviation of its aligned inputs from the runs' median, as a fraction of
    the input's range, and the input where it is largest."""
    lo = max(r.time[0] - o for r, o in zip(runs, al.offsets))
    hi = min(r.time[-1] - o for r, o in zip(runs, al.offsets))
    if hi - lo < 1.0:
        lo = min(r.time[0] - o for r, o in zip(runs, al.offsets))
        hi = max(r.time[-1] - o for r, o in zip(runs, al.offsets))
    g = np.linspace(lo, hi, 1000)
    dev = np.zeros(len(runs))
    worst = [""] * len(runs)
    for name in names:
        x = np.stack([np.interp(g + o, r.time, r.channels[name]) for r, o in zip(runs, al.offsets)])
        med = np.median(x, axis=0)
        rng = float(np.ptp(med)) or 1.0
        d = np.sqrt(np.mean((x - med) ** 2, axis=1)) / rng
        for i in range(len(runs)):
            if d[i] > dev[i]:
                dev[i], worst[i] = d[i], name
    return dev, worst


def _screen(runs: list[Run], rejected: list[Rejected], method: str, profile) -> tuple[list[Run], Alignment]:
    """Align, leave out the runs that are not repetitions, align the rest again."""
    al = align(runs, method, profile)
    if len(runs) < 2:
        return runs, al
    names = varying_inputs(runs, profile)
    dev, worst = _input_deviation(runs, al, names) if names else (np.zeros(len(runs)), [""] * len(runs))
    typical = float(np.median(dev))
    bad = {}
    for i, r in enumerate(runs):
        if al.correlation and al.correlation[i] < MIN_CORRELATION and i != al.reference:
            bad[i] = (f"not a repetition: its inputs correlate only {al.correlation[i]:.2f} with the reference "
                      f"run {runs[al.reference].name} (at least {MIN_CORRELATION} expected)")
        elif dev[i] > MAX_INPUT_DEVIATION and dev[i] > 3.0 * typical:
            bad[i] = (f"not a repetition: input {worst[i]} deviates from the other runs by {100 * dev[i]:.0f} % "
                      f"of its range (RMS; typical {100 * typical:.1f} %)")
    if len(runs) == 2 and (bad or dev.max() > MAX_INPUT_DEVIATION):
        raise ConfigError(f"the two runs {runs[0].name} and {runs[1].name} are not repetitions of one manoeuvre "
                          f"(input correlation {al.correlation[1 - al.reference]:.2f}, input deviation "
                          f"{100 * dev.max():.0f} % of range); with two runs the odd one cannot be told")
    if len(bad) > len(runs) / 2:
        raise ConfigError(f"{len(bad)} of {len(runs)} runs are not repetitions of one manoeuvre: "
                          + "; ".join(f"{runs[i].name}: {why}" for i, why in bad.items()))
    if bad:
        for i, why in bad.items():
            rejected.append(Rejected(runs[i].path, why))
        runs = [r for i, r in enumerate(runs) if i not in bad]
        al = align(runs, method, profile)
    # coverage of the manoeuvre
    spans = [(r.time[0] - o, r.time[-1] - o) for r, o in zip(runs, al.offsets)]
    med_len = float(np.median([b - a for a, b in spans]))
    lo, hi = float(np.median([a for a, _ in spans])), float(np.median([b for _, b in spans]))
    short = {}
    for i, (a, b) in enumerate(spans):
        cover = (min(b, hi) - max(a, lo)) / max(med_len, 1e-9)
        if cover < MIN_COVERAGE:
            short[i] = f"covers only {100 * cover:.0f} % of the manoeuvre the other runs cover"
    if short and len(short) < len(runs):
        for i, why in short.items():
            rejected.append(Rejected(runs[i].path, why))
        runs = [r for i, r in enumerate(runs) if i not in short]
        al = align(runs, method, profile)
    return runs, al


def build_benchmark(runs: list[Run], rejected: list[Rejected] | None = None, rate: float = DEFAULT_RATE,
                    align_method: str = "xcorr", compare: list[str] | None = None, profile=None) -> Benchmark:
    """Checked, aligned, resampled runs with their bands (see the module docstring); `profile`: the
    vehicle's validation profile (rtsim.vehicle.validation: the inputs, the compared channels; None: the
    default vehicle's)."""
    prof = profile or default_profile()
    rejected = list(rejected or [])
    if not runs:
        raise ConfigError("no usable run: " + "; ".join(f"{r.path.name}: {r.reason}" for r in rejected)
                          if rejected else "no runs given")
    if not rate > 0:
        raise ConfigError(f"grid rate {rate} Hz must be > 0")
    runs = _majority_inputs(runs, rejected, prof)
    runs, al = _screen(runs, rejected, align_method, prof)
    notes: list[str] = []
    n = len(runs)
    if n == 1:
        notes.append("one run only: no confidence interval is possible; the model is compared with the run "
                     "itself, without a band (inside_band is null)")
    dt = 1.0 / rate
    a0 = max(r.time[0] - o for r, o in zip(runs, al.offsets))
    a1 = min(r.time[-1] - o for r, o in zip(runs, al.offsets))
    if a1 - a0 < 10 * dt:
        raise ConfigError(f"the aligned runs overlap for only {max(a1 - a0, 0.0):.3g} s")
    t = np.arange(int(np.floor((a1 - a0) / dt + 1e-9)) + 1) * dt
    al = Alignment(al.method, [o + a0 for o in al.offsets], al.correlation, al.reference)
    order = dict.fromkeys([*SENSOR_NAMES, *(c for r in runs for c in r.channels)])   # a vehicle's own channels last
    names = [c for c in order if any(c in r.channels for r in runs)]
    values: dict[str, np.ndarray] = {}
    members: dict[str, int] = {}
    for c in names:
        rows = []
        for r, o in zip(runs, al.offsets):
            if c in r.channels:
                fw = dt if r.rate > 2.0 * rate else None
                rows.append(resample(r.time, r.channels[c], t + o, filter_width=fw))
        values[c] = np.stack(rows)
        members[c] = len(rows)
    for s, a in DERIVED.items():
        if a in values:
            values[s] = np.stack([derive_wheel_speeds({a: row}, dt)[s] for row in values[a]])
            members[s] = members[a]
    inputs = [c for c in prof.inputs if c in values and members[c] == n]
    for c, k in members.items():
        if k < n:
            notes.append(f"channel {c}: recorded in {k} of {n} runs; its band uses those")
    bands = {c: band(v) for c, v in values.items()}
    rep = {}
    for c in inputs:
        b = bands[c]
        rng = float(np.ptp(b.mean))
        spread = float(np.sqrt(np.nanmean(b.std ** 2))) if n > 1 else float("nan")
        rep[c] = {"range": rng, "rms_spread": spread, "max_spread": float(np.nanmax(b.std)) if n > 1 else float("nan"),
                  "relative": spread / rng if rng > 0 and n > 1 else float("nan")}
    sw = bands.get("steering_wheel_angle")
    ay = bands.get("accel_y")
    lateral = bool((sw is not None and np.ptp(sw.mean) > 0.05) or (ay is not None and np.max(np.abs(ay.mean)) > 0.5))
    wanted = list(compare) if compare else list(prof.compared) if prof.compared else \
        [*LONGITUDINAL, *(LATERAL if lateral else ())]
    compared = [c for c in wanted if c in bands and c not in prof.inputs]
    missing = [c for c in wanted if c not in bands]
    if missing:
        notes.append(f"not compared (not recorded): {', '.join(missing)}")
    if not compared:
        raise ConfigError("no output channel to compare: the runs carry none of " + ", ".join(wanted))
    if not inputs:
        raise ConfigError(f"the runs carry no model input ({', '.join(prof.inputs)}): nothing to replay")
    return Benchmark(t, dt, runs, rejected, al, values, bands, inputs, compared, rep, lateral, notes)
