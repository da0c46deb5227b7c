"""The iterative validation loop (the seed's sec. 2.1, third phase, carried to its end):

1. benchmark data from the runs (data, align, benchmark, stats);
2. the vehicle model built once, the mean inputs replayed (replay);
3. per iteration: where the model leaves the band (residuals), every candidate effect not yet in the
   model fitted and ranked (identify), the winner added when the evidence is strong, the runner-up
   reported; stop when every compared channel is inside the band (>= `INSIDE_ENOUGH` of its samples),
   when no candidate helps, or after `max_iterations`;
4. the gap before and after: with two runs or more, every run's own inputs are replayed through the
   model as given and with the identified effects, and the outputs are averaged over the runs exactly
   as the benchmark averages the data (`Result.before` / `after`; the fits use the mean inputs). A
   manoeuvre's events (the onset of motion, the stop and the car rocking after it) happen at slightly
   different times in each run: the data's mean smears them, so the model replayed once with the mean
   inputs, its events crisp, differs from the mean by an averaging artefact that is no missing physics;
   the mean-input replays are kept (`Result.mean_input`) and shown in the report;
5. the new vehicle config with the identified effects and its diff (configwrite), the report
   (report.html, plots, summary.json).

Structural mismatch (issue 15): every residual carries the nuisance adjustments (objective.Nuisance:
axle rolling radii, a small resistance offset; reported, never named, and a model effect they reproduce
is not named either); candidates are judged per channel (identify.channel_evidence); the intervals carry
the model error (identify.joint_uncertainty); when nothing is eligible alone, the sensor effects are
fitted again on top of the best model candidate (_joint_sensor); a model winner is fitted jointly with the model
candidates that promise to explain what it leaves, and with the model effects added in earlier
iterations (joint.joint_model: a first effect that absorbed part of a second is re-fitted with it); the
sensor effects named in earlier iterations are re-fitted beside every later candidate, and their values
again once a model effect has joined after them (_with_named_sensors: a sensor value fitted before a model
effect does not fight it); at the end
every channel is reported as explained, inside the band or structural with its shape
(structural.channel_report), the identified effects' sensitivities are correlated (|r| >= CONFOUNDED:
confounded), and the verdict says "no catalogue effect" or "cannot be told apart" when no effect stands
out from the structural mismatch.

The vehicle's validation profile (rtsim.vehicle.validation, from `open_vehicle(vehicle).validation`)
says what differs between vehicles: the inputs the replay follows, the compared channels, the effect
catalogue, the sensor channels read from the runs, the replayer and the report's line on the manoeuvre.
The workflow takes it once per run and passes it on (the benchmark, the replayer, the result); it holds
no vehicle of its own between runs.

The loop also stops when every channel's normalised cost (objective) is at most 1, i.e. the model is
within the data's own uncertainty: a candidate fitted there would fit noise and averaging artefacts.

Cost per iteration: a joint fit takes at most identify.JOINT_SIMS simulations per pair (joint.JOINT_TOP pairs,
none when no partner promises to move the outputs) and one per-run replay of each run when accepted;
every model effect is screened with two or three simulations (a trial value, one
Gauss-Newton step, halved once when it overshoots), the `REFINE_TOP` best are refined to convergence
(identify.MAX_SIMS simulations at most), the sensor effects one replay of each run for all of them
(_ensemble: they are fitted on the per-run replays averaged, without the mean-input replay's averaging
artefact, and a sensor winner's per-run values reuse those replays); candidates are fitted in parallel by
`workers` processes forked after the model is built (the compiled model is shared, never rebuilt), or
with `ray` (tasks.RayWorkers: an address, "auto" for a local instance on 127.0.0.1, and the executor's
functions, which the command passes in: rtsim.batch.executors.ray_init and ray_map) by Ray tasks (the
iteration's context shipped once to each worker; the same results, in the same order). Each
run's replay inputs (its steering command matched to its measured angle, see replay) are prepared once,
in parallel, before the first per-run replay. A simulation error in a worker comes back as text
(tasks.Failed): a per-run replay that fails leaves the mean-input fit and its linearised interval, said so in
the candidate's note.
"""
from __future__ import annotations

import importlib
import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.vehicle.registry import open_vehicle

from .benchmark import DEFAULT_RATE, Benchmark, build_benchmark
from .data import MIN_RUNS, accel_frame, announce, load_runs, require_runs
from .effectset import Effect, from_mapping
from .identify import (CLEAR, DISCREPANCY_Z, LITTLE, MAX_SIMS, Candidate, Context, add_detail, combine_runs, equivalents,
                       fit_sensor_effects, rank, rebase, refit_named_sensors, run_estimate, sensor_refits, told_apart)
from .crossval import normalised
from .joint import joint_model
from .objective import Objective
from .replay import Replayer, ReplayInputs
from .residuals import Regimes, describe, locate, regimes
from .stats import error_metrics
from .structural import channel_report, correlations
from .tasks import Failed, Quiet, RayWorkers, map_tasks, raise_failed

INSIDE_ENOUGH = 0.95
INSIDE_MOSTLY = 0.90
TRY_WINNERS = 2              # eligible candidates checked run by run before giving up
CONFOUNDED = 0.9             # |correlation| of two identified effects' sensitivities above which they are confounded
SCREEN_SIMS = 3              # trial, one Gauss-Newton step (and that step halved if it overshoots)
REFINE_TOP = 2               # model effects refined to convergence per iteration


@dataclass
class Options:
    vehicle: Path
    runs: list[Path]
    report: Path
    road: Path | None = None
    rate: float = DEFAULT_RATE
    align: str = "xcorr"
    dt: float = 1e-3
    fit_dt: float = 5e-3               # s, the candidate fits' step (replay.Replayer.fit_step)
    max_iterations: int = 4
    workers: int = 2
    ray: RayWorkers | None = None     # re-simulations on Ray (its address and executor, given by the command)
    compare: list[str] | None = None
    accel_frame: str | None = None    # "body" or "level": the runs' accelerometer frame (None: as the runs
                                      # declare it, else body; data.accel_frame)
    progress: object = None           # a Progress-like object with .stage(text, total) / .advance()
    min_runs: int = MIN_RUNS          # stop unless this many runs pass the data checks (data.require_runs)
    read_mcap: object = None          # path -> (messages, info): how MCAP runs are read (the command passes
                                      # bridge.mcap_recorder.read_recording; None: MCAP runs are refused)


@dataclass
class Iteration:
    index: int
    model: list[str]                  # effects in the model at the start of the iteration
    cost: float
    metrics: dict                     # per channel rms/max/inside_band at the start
    where: list[str]                  # where the excess concentrates
    candidates: list[Candidate]
    winner: Candidate | None
    runner_up: Candidate | None
    verdict: str
    seconds: float
    equivalent: list = field(default_factory=list)     # (label, distance) of indistinguishable candidates
    partners: list = field(default_factory=list)       # model effects added jointly with the winner (Candidate)
    refitted: list = field(default_factory=list)       # (label before, label after) of earlier effects re-fitted
    joint: dict = field(default_factory=dict)          # the joint fit: members, correlations, evidence

    def summary(self) -> dict:
        return {"iteration": self.index, "model_effects": self.model, "cost": self.cost, "metrics": self.metrics,
                "where": self.where, "verdict": self.verdict,
                "indistinguishable": [{"effect": lab, "distance": d} for lab, d in self.equivalent],
                "winner": self.winner.summary() if self.winner else None,
                "runner_up": self.runner_up.summary() if self.runner_up else None,
                "partners": [c.summary() for c in self.partners],
                "refitted": [{"before": a, "after": b} for a, b in self.refitted], "joint": self.joint,
                "candidates": [c.summary() for c in self.candidates], "seconds": self.seconds}


@dataclass
class Result:
    options: Options
    bench: Benchmark
    inputs: ReplayInputs
    replayer: Replayer
    objective: Objective
    regimes: Regimes
    base_effects: list[Effect]
    effects: list[Effect]             # identified, in the order added
    before: dict                      # model outputs before (config as given)
    after: dict                       # model outputs after
    iterations: list[Iteration]
    verdict: str
    profile: object                   # the vehicle's validation profile (rtsim.vehicle.validation)
    timings: dict = field(default_factory=dict)
    mean_input: Mapping = field(default_factory=dict)   # "before"/"after": the mean-input replays' outputs
    comparison: str = ""              # how `before` and `after` were made
    config_path: Path | None = None
    diff: str = ""
    nuisance: dict = field(default_factory=dict)     # name -> (value, unit) fitted to `after`, never named
    channels: dict = field(default_factory=dict)     # structural.channel_report of `after`
    correlations: list = field(default_factory=list)  # (effect, effect, correlation of their sensitivities)
    accel_frame: str = "body"                        # the frame the model's accelerations were compared in
    confounded: list = field(default_factory=list)    # pairs the data cannot separate

    def metrics(self, outputs: dict, adjusted: bool = False) -> dict:
        """Per compared channel, the error metrics of `outputs`; `adjusted`: with the nuisance adjustments
        fitted to them applied (what is left beside the structural mismatch they stand for)."""
        if adjusted:
            outputs = self.objective.adjusted(outputs)
        return {c: error_metrics(outputs[c], self.bench.bands[c]) for c in self.bench.compared}


def _fit_model_candidates(ctx: Context, names: list[str], workers: int, progress) -> list[Candidate]:
    """Screen every model effect (trial + one damped Gauss-Newton step), then refine the `REFINE_TOP` best to
    convergence, continuing from their screening simulations; candidates run in parallel."""
    screened = raise_failed(map_tasks(ctx, [("fit", n, SCREEN_SIMS, None) for n in names], workers, progress))
    screened.sort(key=lambda c: c.cost)
    top = [c for c in screened if c.reduction > LITTLE][:REFINE_TOP]
    refined = raise_failed(map_tasks(ctx, [("fit", c.effect.name, MAX_SIMS, c.points) for c in top], workers,
                                 progress))
    byname = {c.effect.name: c for c in refined}
    out = []
    for c in screened:
        if c.effect.name in byname:
            out.append(byname[c.effect.name])
        else:
            add_detail(c, "screened (trial and one damped Gauss-Newton step), not refined")
            out.append(c)
    ctx.replayer.simulations += sum(c.sims for c in out)
    return out


def _joint_sensor(ctx: Context, ranked: list[Candidate]) -> list[Candidate]:
    """Several effects at once: when no candidate is eligible on its own, the sensor effects are fitted
    again on top of the best model candidate (a sensor bias and a model effect on one channel hide each
    other). A sensor effect eligible there (it explains its own channel with the model effect in place)
    is returned as this iteration's winner, at its jointly fitted value and judged on the current model
    (the model effect is refitted in the next iteration with it in place); the correlation of the two
    sensitivities is in its note."""
    models = [c for c in ranked if c.kind == "model" and c.plausible and c.raw is not None and c.predicts]
    if not models:
        return []
    m = models[0]
    rp = ctx.replayer
    both = Context(ctx.bench, ctx.objective, rp, ctx.inputs, [*ctx.effects, m.effect], m.outputs, m.raw, m.cost,
                   ctx.n_runs, ctx.deviations)
    joint = sorted((c for c in fit_sensor_effects(both) if c.eligible), key=lambda c: c.score)
    out = []
    for j in joint[:TRY_WINNERS]:
        same = next((c for c in ranked if c.kind == "sensor" and c.effect.key == j.effect.key), None)
        if same is None:
            continue
        same.effect.params.update(j.effect.params)
        same.effect.adopt_interval(j.effect)
        same.theta, same.u_theta = j.theta, j.u_theta
        same.outputs = rp.reported(ctx.raw, ctx.inputs.t, [*ctx.effects, same.effect])
        corr = float(m.J @ j.J) / (float(np.linalg.norm(m.J) * np.linalg.norm(j.J)) or 1.0) if m.J is not None \
            else float("nan")
        add_detail(same, (
            f"judged jointly with {m.effect.label()}: with it in place it explains "
            f"{100 * j.local_reduction:.0f} % of its channel (correlation of the two sensitivities {corr:+.2f})"))
        same.joint = (m.effect.label(), corr)
        out.append(same)
    return out


# ------------------------------------------------------------------------------------ the loop
def _metrics(bench: Benchmark, outputs: dict) -> dict:
    return {c: error_metrics(outputs[c], bench.bands[c]) for c in bench.compared}


def _inside(metrics: dict, share: float = None) -> bool:
    vals = [m["inside_band"] for m in metrics.values()]
    return all(v is not None and v >= (INSIDE_ENOUGH if share is None else share) for v in vals)


def _with_named_sensors(ctx: Context, named: list[Effect], workers: int, cache: dict,
                        fitted_on: dict) -> tuple[Objective, list]:
    """The iteration's objective, in which the sensor effects named so far are re-fitted beside the
    nuisance adjustments at every residual (identify.sensor_refits: a model effect judged later is not
    fought by a sensor value fitted without it), after re-fitting the values of those fitted on another
    model than the one that now stands (identify.refit_named_sensors, on the per-run replays averaged
    where there are any, as the sensor effects are fitted; `fitted_on`: id of the effect -> the model
    effects it was fitted with, _model_key, kept up to date here; an effect not in it was named in the
    previous iteration, on this model): (objective, (label before, label after) of the values that
    moved)."""
    sensors = [e for e in named if e.kind == "sensor"]
    if not sensors:
        return ctx.objective, []
    key = _model_key(ctx.effects)
    stale = [e for e in sensors if fitted_on.setdefault(id(e), key) != key]
    raws = _run_raws(ctx, ctx.effects, workers, cache)
    raw = {c: np.mean([r[c] for r in raws], axis=0) for c in raws[0]} if raws else ctx.raw
    moved = refit_named_sensors(ctx, raw, ctx.effects, stale) if stale else []
    for e in stale:
        fitted_on[id(e)] = key
    return ctx.objective.refitting(*sensor_refits(ctx, raw, ctx.effects, sensors)), moved


def _prepare_runs(ctx: Context, workers: int) -> None:
    """Each run's replay inputs (steering matched), once per benchmark, in parallel."""
    rp, bench = ctx.replayer, ctx.bench
    if rp.prepared(bench):
        return
    rp.steering_command(rp.inputs(bench), rp.dt)    # the mean's, which every run's starts from: made once, here
    for i, ri in enumerate(map_tasks(ctx, [("inputs", i) for i in range(bench.n)], workers, Quiet())):
        if not isinstance(ri, Failed):
            rp.remember(bench, i, ri)


def _model_key(effects: list[Effect]) -> tuple:
    """What the car's motion depends on: the model effects and their values (sensor effects act on the
    readings only)."""
    return tuple(sorted(e.label() for e in effects if e.kind == "model"))


def _run_raws(ctx: Context, effects: list[Effect], workers: int, cache: dict) -> list | None:
    """Every run's own inputs replayed (at the model's step) with the model effects of `effects`, before
    the sensor model: one simulation per run, made once per set of model effects (`cache`) and reused by
    every later use with the same motion (the sensor effects' fits, the before/after comparison). None
    with one run or when a replay fails (`cache` then holds the reason under "failed")."""
    bench = ctx.bench
    if bench.n < 2:
        cache["failed"] = "one run"
        return None
    key = _model_key(effects)
    if key not in cache:
        _prepare_runs(ctx, workers)
        raws = map_tasks(ctx, [("raw", effects, i) for i in range(bench.n)], workers, Quiet())
        ctx.replayer.simulations += bench.n
        failed = [f"{bench.runs[i].name}: {r.message}" for i, r in enumerate(raws) if isinstance(r, Failed)]
        if failed:
            cache["failed"] = "a per-run replay failed (" + "; ".join(failed) + ")"
        cache[key] = None if failed else raws
    return cache[key]


def _replay_runs(ctx: Context, effects: list[Effect], workers: int, cache: dict) -> tuple[dict | None, str]:
    """The model's counterpart of the benchmark mean: every run's own inputs replayed (at the model's
    step) with `effects`, the outputs averaged over the runs exactly as the data are. (None, why) with
    one run or when a replay fails."""
    raws = _run_raws(ctx, effects, workers, cache)
    if raws is None:
        return None, cache.get("failed", "")
    rp, bench = ctx.replayer, ctx.bench
    outs = [rp.reported(r, bench.t, effects) for r in raws]
    return {c: np.mean([o[c] for o in outs], axis=0) for c in outs[0]}, ""


def _ensemble(ctx: Context, workers: int, cache: dict) -> tuple[Context | None, list | None]:
    """The iteration's model (its physical outputs) replayed with every run's own inputs and averaged over
    the runs like the data, as a context to fit the sensor effects in, and the per-run replays. A sensor
    effect is linear in the reading (a bias, a scale, a delay), so on the average of the replays it is
    the average of each replay with the effect: fitted there it is judged without the averaging
    artefact the mean-input replay leaves (a stop smeared in the data's mean, crisp in the replay, that a
    scale of accel_x cannot explain). (None, None) with one run or when a replay fails."""
    bench, rp = ctx.bench, ctx.replayer
    raws = _run_raws(ctx, ctx.effects, workers, cache)
    if raws is None:
        return None, None
    raw = {c: np.mean([r[c] for r in raws], axis=0) for c in raws[0]}
    out = rp.reported(raw, bench.t, ctx.effects)
    # each run's replay minus their mean, normalised: the cross-validation predicts a run from its inputs
    obj = ctx.objective
    per_run = [normalised(obj, rp.reported(r, bench.t, ctx.effects)) for r in raws]
    mean = np.mean(per_run, axis=0)
    ctx.deviations = [x - mean for x in per_run]
    return Context(bench, obj, rp, ctx.inputs, ctx.effects, out, raw, obj.cost(out), ctx.n_runs,
                   ctx.deviations, raws), raws


class MeanInputReplays(Mapping):
    """The mean inputs replayed at the model's step before ("before": the config as given) and after
    ("after": with the identified effects; the same replay when none were), each made when first asked
    for and kept: the report shows them beside the per-run replays, which the comparison uses whenever
    there are two runs or more, so a workflow whose report is not written (the benchmark) never pays for
    them."""

    def __init__(self, replayer: Replayer, inputs: ReplayInputs, base: list[Effect], effects: list[Effect]):
        self._rp, self._inp = replayer, inputs
        self._effects = {"before": list(base), "after": [*base, *effects]}
        self._same = not effects
        self._made: dict = {}

    def __getitem__(self, key: str) -> dict:
        if key == "after" and self._same:
            key = "before"
        if key not in self._made:
            effs = self._effects[key]
            self._made[key] = self._rp.reported(self._rp.simulate(self._inp, effs), self._inp.t, effs)
        return self._made[key]

    def __iter__(self):
        return iter(self._effects)

    def __len__(self) -> int:
        return len(self._effects)


def _sensor_names(profile, replayer: Replayer | None) -> tuple[str, ...]:
    """The validated vehicle's sensor channels (its channel dictionary), without building its model."""
    if replayer is not None:
        return getattr(replayer, "sensor_names", None) or replayer.model.channels.sensor_names
    return profile.sensor_names


def make_replayer(profile, vehicle: Path, road: Path | None, dt: float, fit_dt: float):
    """The replayer the vehicle's validation profile names ("module:Class"), built on the vehicle file."""
    module, _, name = profile.replayer.partition(":")
    return getattr(importlib.import_module(module), name)(vehicle, road, dt, fit_dt)


def run(opts: Options, replayer: Replayer | None = None) -> Result:
    """The whole workflow; `replayer`: a model already built from opts.vehicle (and opts.road), reused.
    With opts.ray, Ray is connected for the run's duration (and shut down after, when this started it)."""
    if not opts.ray:
        return _run(opts, replayer)
    import sys

    ray = sys.modules.get("ray")                # None: not imported, or blocked as missing
    started = ray is None or not ray.is_initialized()
    if started:
        opts.ray.init(opts.ray.address)
    try:
        return _run(opts, replayer)
    finally:
        if started:
            sys.modules["ray"].shutdown()


def _run(opts: Options, replayer: Replayer | None) -> Result:
    prog = opts.progress or Quiet()
    tm = {}
    t0 = time.perf_counter()
    # the vehicle's inputs, compared channels, effect catalogue and replayer
    profile = replayer.profile if replayer is not None else open_vehicle(opts.vehicle).validation
    prog.stage("loading runs", None)
    runs, rejected = load_runs(opts.runs, _sensor_names(profile, replayer), opts.read_mcap)
    announce(rejected)                    # one line per run left out, on stderr
    require_runs(runs, rejected, opts.min_runs)
    frame = accel_frame(runs, opts.accel_frame)
    bench = build_benchmark(runs, rejected, opts.rate, opts.align, opts.compare, profile)
    announce(bench.rejected[len(rejected):])
    require_runs(bench.runs, bench.rejected, opts.min_runs)
    tm["data"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    prog.stage("building the model", None)
    rp = replayer or make_replayer(profile, opts.vehicle, opts.road, opts.dt, opts.fit_dt)
    rp.simulations = 0
    rp.accel_frame = frame
    inp = rp.inputs(bench)
    base = from_mapping(getattr(rp.config, "effects", None))
    tm["model_build"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    prog.stage("replaying mean inputs", None)
    raw = rp.simulate(inp, base, fit=True)           # the fits' starting point, at the fitting step
    out = rp.reported(raw, bench.t, base)
    tm["first_simulation"] = time.perf_counter() - t2
    obj = Objective.from_benchmark(bench, rp.wheel_radius)
    reg = regimes(bench, rp.wheel_radius)
    cat = profile.effects
    effects: list[Effect] = []
    latest: dict = {}                   # effect key -> the candidate that fitted its current value
    iterations: list[Iteration] = []
    verdict = ""
    replays: dict = {}                  # model effects -> every run's replay (_run_raws)
    sensed: dict = {}                   # named sensor effect (id) -> the model effects its value was fitted with
    workers = opts.ray or max(1, min(opts.workers, os.cpu_count() or 1))
    for k in range(1, opts.max_iterations + 1):
        ti = time.perf_counter()
        current = [*base, *effects]
        iobj, resensed = _with_named_sensors(Context(bench, obj, rp, inp, current, out, raw, 0.0, bench.n), effects,
                                             workers, replays, sensed)
        if resensed:
            out = rp.reported(raw, bench.t, current)
        metrics = _metrics(bench, out)
        cost = iobj.cost(out)
        where = describe(locate(bench, out, reg))
        label = [e.label() for e in effects]
        within = max(iobj.channel_cost(out).values()) <= 1.0
        if _inside(metrics) or within:
            how = (f"inside the 95 % band on every compared channel (>= {100 * INSIDE_ENOUGH:.0f} % of samples)"
                   if _inside(metrics) else "within the data's own uncertainty on every compared channel (mean "
                   "squared residual below the squared standard error of the mean)")
            verdict = f"the model is {how}" + (" after adding " + " and ".join(label) if effects else
                                               " as given: no missing effect")
            iterations.append(Iteration(k, label, cost, metrics, where, [], None, None, verdict,
                                        time.perf_counter() - ti, refitted=list(resensed)))
            break
        ctx = Context(bench, iobj, rp, inp, current, out, raw, cost, bench.n)
        taken = {e.name for e in current}
        names = [n for n, s in cat.items() if s.kind == "model" and n not in taken]
        prog.stage(f"iteration {k}: fitting effects", len(names) + REFINE_TOP + 1 + bench.n)
        ens, raws = _ensemble(ctx, workers, replays)      # first: it gives ctx the runs' deviations
        cands = _fit_model_candidates(ctx, names, workers, prog)
        sensors = fit_sensor_effects(ens or ctx)
        if ens is not None:
            rebase(sensors, ctx)
            for c in sensors:
                add_detail(c, "judged on the per-run replays averaged")
        cands += sensors
        prog.advance()
        ranked = rank(cands)
        win = None
        trials = [c for c in ranked if c.eligible][:TRY_WINNERS]
        if not trials:
            trials = _joint_sensor(ctx, ranked)
        for cand in trials:
            if bench.n >= 2:
                _prepare_runs(ctx, workers)                 # the value and its interval from the runs one by one
                if cand.kind == "sensor" and raws is not None:      # its motion is the replays'
                    ests = [run_estimate(ctx, cand, i, raws[i]) for i in range(bench.n)]
                else:
                    ests = map_tasks(ctx, [("run", cand, i) for i in range(bench.n)], workers, prog)
                    rp.simulations += bench.n
                failed = [f"{bench.runs[i].name}: {r.message}" for i, r in enumerate(ests) if isinstance(r, Failed)]
                if failed:
                    add_detail(cand, (
                        "per-run replay failed (" + "; ".join(failed) + "): the mean-input fit and its "
                        "linearised interval kept"))
                combine_runs(cand, [math.nan if isinstance(r, Failed) else r for r in ests])
            if abs(cand.theta) >= CLEAR * cand.u_theta:
                win = cand
                break
            cand.note = ("Its 95 % interval from the runs one by one includes the off value: the runs do not "
                         "agree that it is there.")
        apart = told_apart(ctx, win, ranked, CONFOUNDED) if win is not None else []
        if apart:
            others = " or ".join(c.effect.label() for c in apart)
            apart_text = (f"{win.effect.label()} and {others} change the outputs alike (beyond the nuisance "
                          f"adjustments) and neither predicts the left-out runs significantly better: the data "
                          f"cannot tell which it is, so neither is named")
            for c in (win, *apart):
                c.note = "The data cannot tell it from " + (others if c is win else win.effect.label()) + \
                    ": the two change the outputs alike and predict the left-out runs equally well."
            win = None
        if win is None and apart:
            verdict = ((f"after adding {' and '.join(label)}, " if effects else "")
                       + "cannot be told apart: " + apart_text)
            runner = next((c for c in ranked if c.plausible), None)
            iterations.append(Iteration(k, label, cost, metrics, where, ranked, None, runner, verdict,
                                        time.perf_counter() - ti, refitted=list(resensed)))
            break
        if win is None:
            best = ranked[0] if ranked else None
            why = (f"; the best candidate, {best.effect.label()}, was turned down: "
                   f"{best.note or 'it did not improve the prediction of left-out runs.'}") if best else ""
            close = [c for c in ranked if c.plausible and c.kind == "model" and not c.outweighs_structure
                     and c.predicts and not c.confounded]
            if close:
                c = close[0]
                why = (f"; {c.effect.label()} would change {', '.join(c.signature)} by {c.moved:.2g} standard "
                       f"errors, less than {DISCREPANCY_Z:.2f} times the mismatch left there ({max(c.left, 1.0):.2g}): the "
                       f"data cannot tell it apart from the structural mismatch")
            if not effects and _inside(metrics, INSIDE_MOSTLY):
                verdict = ("no missing effect found: the model agrees with the benchmark (at least "
                           f"{100 * INSIDE_MOSTLY:.0f} % of every channel inside the band) and no candidate removes a "
                           f"significant share of what is left{why}")
            elif not effects and close:
                verdict = ("cannot be told apart: no catalogue effect stands out from the structural mismatch"
                           f"{why}")
            elif not effects:
                verdict = ("no catalogue effect explains this: no candidate improves the prediction of left-out "
                           f"runs and stands out from the structural mismatch{why}")
            else:
                verdict = (f"after adding {' and '.join(label)}, no further candidate helps{why}")
            runner = next((c for c in ranked if c.plausible), None)
            iterations.append(Iteration(k, label, cost, metrics, where, ranked, None, runner, verdict,
                                        time.perf_counter() - ti, refitted=list(resensed)))
            break
        if bench.n >= 2:                     # outputs at the per-run value
            eff = win.effect
            if win.kind == "model":
                win.raw = rp.simulate(inp, [*current, eff], fit=True)
                win.outputs = rp.reported(win.raw, bench.t, [*current, eff])
            else:
                win.outputs = rp.reported(raw, bench.t, [*current, eff])
        joint, tried = None, {}
        if win.kind == "model" and win.raw is not None and win.J is not None and win.coord is not None:
            earlier = [latest[e.key] for e in effects if e.kind == "model" and e.key in latest]
            joint = joint_model(ctx, win, ranked, earlier, workers, prog, tried)
        refitted = list(resensed)
        if joint is not None:
            for old, new in zip(joint.refitted, joint.members):
                effects[effects.index(old.effect)] = new.effect
                refitted.append((old.effect.label(), new.effect.label()))
                latest[new.effect.key] = new
            w = joint.members[len(joint.refitted)]
            win.effect.params.update(w.effect.params)
            win.effect.adopt_interval(w.effect)
            win.theta, win.u_theta, win.J, win.per_run = w.theta, w.u_theta, w.J, w.per_run
            win.raw, win.outputs = joint.raw, joint.outputs
        ties = equivalents(obj, win, ranked)
        runner = next((c for c in ranked if c is not win and c.plausible), None)
        for c in ranked:
            if c is not win and not c.note:
                c.note = f"{win.effect.label()} predicted the left-out runs better."
        v = f"{win.effect.label()} removes {100 * win.reduction:.0f} % of the disagreement" + (
            f" and {100 * win.cv.gain:.0f} % of the error in predicting a left-out run" if win.cv is not None else "")
        if ties:
            v += ("; indistinguishable on this manoeuvre from " + ", ".join(
                f"{c.effect.label()} (responses {d:.2f} standard errors apart)" for c, d in ties) +
                  ": the data cannot tell these apart, the best-scoring one is added")
        if runner:
            v += (f"; runner-up {runner.effect.label()} ({100 * runner.reduction:.0f} %" + (
                f", {100 * runner.cv.gain:.0f} % of the left-out runs' error" if runner.cv is not None else "") + ")")
        effects.append(win.effect)
        latest[win.effect.key] = win
        partners = []
        if joint is not None and joint.text:
            v += "; " + joint.text
        if tried.get("rejected"):
            v += "; " + tried["rejected"]
        if joint is not None and joint.partner is not None:
            partners.append(joint.partner)
            effects.append(joint.partner.effect)
            latest[joint.partner.effect.key] = joint.partner
        out = win.outputs
        if win.kind == "model":
            raw = win.raw if win.raw is not None else rp.simulate(inp, [*base, *effects], fit=True)
        if not _inside(_metrics(bench, out)):
            v += "; the model is still outside the band: no single effect explains all of it, iterating"
        it = Iteration(k, label, cost, metrics, where, ranked, win, runner, v, time.perf_counter() - ti)
        it.equivalent = [(c.effect.label(), d) for c, d in ties]
        it.partners, it.refitted = partners, refitted
        it.joint = tried
        iterations.append(it)
    else:
        verdict = f"stopped after {opts.max_iterations} iterations: " + iterations[-1].verdict
        _with_named_sensors(Context(bench, obj, rp, inp, [*base, *effects], out, raw, 0.0, bench.n), effects, workers,
                            replays, sensed)
    t3 = time.perf_counter()
    replayed = MeanInputReplays(rp, inp, base, effects)
    if bench.n >= 2:
        prog.stage("replaying every run before and after", None)
    ctx = Context(bench, obj, rp, inp, [*base, *effects], {}, {}, 0.0, bench.n)
    ens_before, why = _replay_runs(ctx, base, workers, replays)
    ens_after = _replay_runs(ctx, [*base, *effects], workers, replays)[0] if ens_before else None
    if ens_before is not None and ens_after is not None:
        before, after = ens_before, ens_after
        comparison = ("per-run replays averaged: each run's own inputs replayed and the model outputs averaged "
                      "over the runs like the data (the mean-input replay is kept in the report)")
    else:
        before, after = replayed["before"], replayed["after"]
        comparison = f"the mean inputs replayed ({why or 'a per-run replay failed'})"
    tm["final_simulation"] = time.perf_counter() - t3
    winners = [latest[e.key] for e in effects if e.key in latest]
    explained: dict[str, list[str]] = {}
    for w in winners:
        for c in w.signature:
            explained.setdefault(c, []).append(w.effect.label())
    from .data import unit
    chans = channel_report(bench, obj, after, explained, {c: unit(c) for c in bench.compared})
    corr = correlations(winners)
    confounded = [(a, b, r) for a, b, r in corr if abs(r) >= CONFOUNDED]
    structural = [f"{c}: {v['text']}" for c, v in chans.items() if v["status"] == "structural"]
    if structural:
        verdict += "; structural mismatch (not in the catalogue) remains on " + "; ".join(structural)
        if not effects and "cannot be told apart" not in verdict:
            verdict += ("; a catalogue effect that changes these channels less than this mismatch cannot be told "
                        "apart from it")
    if confounded:
        verdict += "; confounded (the data cannot separate them): " + "; ".join(
            f"{a} and {b} (correlation {r:+.2f})" for a, b, r in confounded)
    tm["identification"] = sum(it.seconds for it in iterations)
    tm["simulations"] = rp.simulations
    tm["total"] = time.perf_counter() - t0
    return Result(opts, bench, inp, rp, obj, reg, base, effects, before, after, iterations, verdict, profile, tm,
                  mean_input=replayed, comparison=comparison, nuisance=obj.nuisance_values(after),
                  channels=chans, correlations=corr, confounded=confounded, accel_frame=frame)
