"""The iterative validation loop (the seed's sec. 2.1, third phase, carried to its end):

1. benchmark data from the runs (data, align, benchmark, stats);
2. the vehicle model built once, the mean inputs replayed (replay);
3. per iteration: where the model leaves the band (residuals), every candidate effect not yet in the
   model fitted and ranked (identify), the winner added when the evidence is strong, the runner-up
   reported; stop when every compared channel is inside the band (>= `INSIDE_ENOUGH` of its samples),
   when no candidate helps, or after `max_iterations`;
4. the new vehicle config with the identified effects and its diff (configwrite), the report
   (report.html, plots, summary.json).

The loop also stops when every channel's normalised cost (objective) is at most 1, i.e. the model is
within the data's own uncertainty: a candidate fitted there would fit noise and averaging artefacts.

Cost per iteration: every model effect is screened with two simulations (a trial value and one
Gauss-Newton step), the `REFINE_TOP` best are refined to convergence (identify.MAX_SIMS simulations at
most), sensor effects need none; candidates are fitted in parallel by `workers` processes forked after
the model is built (the compiled model is shared, never rebuilt). The loop also stops when every
channel's normalised cost (objective) is at most 1, i.e. the model is within the data's own
uncertainty: a candidate fitted there would fit noise and averaging artefacts.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import sensorfx
from .benchmark import DEFAULT_RATE, Benchmark, build_benchmark
from .data import load_runs
from .effectset import Effect, catalogue, from_mapping
from .identify import (MAX_SIMS, Candidate, Context, combine_runs, equivalents, evidence_strength,
                       fit_model_effect, fit_sensor_effects, rank, run_estimate)
from .objective import Objective
from .replay import Replayer, ReplayInputs
from .residuals import Regimes, describe, locate, regimes
from .stats import error_metrics

INSIDE_ENOUGH = 0.95
INSIDE_MOSTLY = 0.90
TRY_WINNERS = 2              # eligible candidates checked run by run before giving up
CLEAR = 2.0                  # a winner's value must lie this many 95 % half-widths from the off value
SCREEN_SIMS = 2              # trial and one Gauss-Newton step per model effect
REFINE_TOP = 3               # model effects refined to convergence per iteration


@dataclass
class Options:
    vehicle: Path
    runs: list[Path]
    report: Path
    road: Path | None = None
    rate: float = DEFAULT_RATE
    align: str = "xcorr"
    dt: float = 1e-3
    fit_dt: float = 2e-3
    max_iterations: int = 4
    workers: int = 2
    compare: list[str] | None = None
    progress: object = None           # a Progress-like object with .stage(text, total) / .advance()


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

    def summary(self) -> dict:
        return {"iteration": self.index, "model_effects": self.model, "cost": self.cost, "metrics": self.metrics,
                "where": self.where, "verdict": self.verdict,
                "indistinguishable": [{"effect": lab, "distance": d} for lab, d in self.equivalent],
                "winner": self.winner.summary() if self.winner else None,
                "runner_up": self.runner_up.summary() if self.runner_up else None,
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
    timings: dict = field(default_factory=dict)
    config_path: Path | None = None
    diff: str = ""

    def metrics(self, outputs: dict) -> dict:
        return {c: error_metrics(outputs[c], self.bench.bands[c]) for c in self.bench.compared}


class _Quiet:
    def stage(self, text: str, total: int | None = None) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


# ------------------------------------------------------------------------------ parallel fitting
_CTX: Context | None = None


def _task(task: tuple):
    """One unit of parallel work on the iteration's context: ("fit", name, budget, seed) or
    ("run", candidate, run index)."""
    if task[0] == "fit":
        return fit_model_effect(_CTX, *task[1:])
    return run_estimate(_CTX, task[1], task[2])


def _map(ctx: Context, tasks: list[tuple], workers: int, progress) -> list:
    """The tasks' results, in order, computed by `workers` forked processes."""
    global _CTX
    _CTX = ctx
    out = []
    try:
        if workers > 1 and len(tasks) > 1 and "fork" in mp.get_all_start_methods():
            with mp.get_context("fork").Pool(min(workers, len(tasks))) as pool:
                for res in pool.imap(_task, tasks):
                    out.append(res)
                    progress.advance()
        else:
            for t in tasks:
                out.append(_task(t))
                progress.advance()
    finally:
        _CTX = None
    return out


def _fit_model_candidates(ctx: Context, names: list[str], workers: int, progress) -> list[Candidate]:
    """Screen every model effect (trial + one Gauss-Newton step), then refine the `REFINE_TOP` best to
    convergence, continuing from their screening simulations; candidates run in parallel."""
    screened = _map(ctx, [("fit", n, SCREEN_SIMS, None) for n in names], workers, progress)
    screened.sort(key=lambda c: c.cost)
    top = [c for c in screened[:REFINE_TOP] if c.reduction > 0.0]
    refined = _map(ctx, [("fit", c.effect.name, MAX_SIMS, c.points) for c in top], workers, progress)
    byname = {c.effect.name: c for c in refined}
    out = []
    for c in screened:
        if c.effect.name in byname:
            out.append(byname[c.effect.name])
        else:
            c.note = (c.note + "; " if c.note else "") + "screened (trial and one step), not refined"
            out.append(c)
    ctx.replayer.simulations += sum(c.sims for c in out)
    return out


# ------------------------------------------------------------------------------------ the loop
def _metrics(bench: Benchmark, outputs: dict) -> dict:
    return {c: error_metrics(outputs[c], bench.bands[c]) for c in bench.compared}


def _inside(metrics: dict, share: float = None) -> bool:
    vals = [m["inside_band"] for m in metrics.values()]
    return all(v is not None and v >= (INSIDE_ENOUGH if share is None else share) for v in vals)


def run(opts: Options, replayer: Replayer | None = None) -> Result:
    """The whole workflow; `replayer`: a model already built from opts.vehicle (and opts.road), reused."""
    prog = opts.progress or _Quiet()
    tm = {}
    t0 = time.perf_counter()
    prog.stage("loading runs", None)
    runs, rejected = load_runs(opts.runs)
    bench = build_benchmark(runs, rejected, opts.rate, opts.align, opts.compare)
    tm["data"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    prog.stage("building the model", None)
    rp = replayer or Replayer(opts.vehicle, opts.road, opts.dt, opts.fit_dt)
    rp.simulations = 0
    inp = rp.inputs(bench)
    base = from_mapping(getattr(rp.config, "effects", None))
    tm["model_build"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    prog.stage("replaying mean inputs", None)
    before = sensorfx.apply(rp.simulate(inp, base), bench.t, base)
    raw = rp.simulate(inp, base, fit=True)           # the fits' starting point, at the fitting step
    out = sensorfx.apply(raw, bench.t, base)
    tm["first_simulation"] = (time.perf_counter() - t2) / 2
    obj = Objective.from_benchmark(bench)
    reg = regimes(bench, rp.wheel_radius)
    cat = catalogue()
    effects: list[Effect] = []
    iterations: list[Iteration] = []
    verdict = ""
    workers = max(1, min(opts.workers, os.cpu_count() or 1))
    for k in range(1, opts.max_iterations + 1):
        ti = time.perf_counter()
        current = [*base, *effects]
        metrics = _metrics(bench, out)
        cost = obj.cost(out)
        where = describe(locate(bench, out, reg))
        label = [e.label() for e in effects]
        within = max(obj.channel_cost(out).values()) <= 1.0
        if _inside(metrics) or within:
            how = (f"inside the 95 % band on every compared channel (>= {100 * INSIDE_ENOUGH:.0f} % of samples)"
                   if _inside(metrics) else "within the data's own uncertainty on every compared channel (mean "
                   "squared residual below the squared standard error of the mean)")
            verdict = f"the model is {how}" + (" after adding " + " and ".join(label) if effects else
                                               " as given: no missing effect")
            iterations.append(Iteration(k, label, cost, metrics, where, [], None, None, verdict,
                                        time.perf_counter() - ti))
            break
        ctx = Context(bench, obj, rp, inp, current, out, raw, cost, bench.n)
        taken = {e.name for e in current}
        names = [n for n, s in cat.items() if s.kind == "model" and n not in taken]
        prog.stage(f"iteration {k}: fitting effects", len(names) + REFINE_TOP + 1 + bench.n)
        cands = _fit_model_candidates(ctx, names, workers, prog)
        cands += fit_sensor_effects(ctx)
        prog.advance()
        ranked = rank(cands)
        win = None
        for cand in [c for c in ranked if c.eligible][:TRY_WINNERS]:
            if bench.n >= 2:                 # the value and its interval from the runs one by one
                thetas = _map(ctx, [("run", cand, i) for i in range(bench.n)], workers, prog)
                rp.simulations += bench.n
                combine_runs(cand, thetas)
            if abs(cand.theta) >= CLEAR * cand.u_theta:
                win = cand
                break
            cand.note = (cand.note + "; " if cand.note else "") + (
                f"not added: its 95 % interval (+- {cand.u_theta:.2g} in the fitted coordinate) does not clear the "
                f"off value by a factor {CLEAR:g}")
        if win is None:
            best = ranked[0] if ranked else None
            why = (f"; the best candidate, {best.effect.label()}, removes {100 * best.reduction:.0f} % "
                   f"({best.note or 'evidence too weak'})") if best else ""
            if not effects and _inside(metrics, INSIDE_MOSTLY):
                verdict = ("no missing effect found: the model agrees with the benchmark (at least "
                           f"{100 * INSIDE_MOSTLY:.0f} % of every channel inside the band) and no candidate removes a "
                           f"significant share of what is left{why}")
            elif not effects:
                verdict = ("no single effect explains this: no candidate of the catalogue removes a significant, "
                           f"plausible share of the disagreement{why}")
            else:
                verdict = (f"after adding {' and '.join(label)}, no further candidate helps{why}")
            runner = next((c for c in ranked if c.plausible), None)
            iterations.append(Iteration(k, label, cost, metrics, where, ranked, None, runner, verdict,
                                        time.perf_counter() - ti))
            break
        if bench.n >= 2:                     # outputs at the per-run value
            eff = win.effect
            if win.kind == "model":
                win.raw = rp.simulate(inp, [*current, eff], fit=True)
                win.outputs = sensorfx.apply(win.raw, bench.t, [*current, eff])
            else:
                win.outputs = sensorfx.apply(raw, bench.t, [*current, eff])
        ties = equivalents(obj, win, ranked)
        runner = next((c for c in ranked if c is not win and c.plausible), None)
        gap = (runner.ic - win.ic) if runner else float("inf")
        v = f"{win.effect.label()} removes {100 * win.reduction:.0f} % of the disagreement (IC {win.delta_ic:+.0f})"
        if ties:
            v += ("; indistinguishable on this manoeuvre from " + ", ".join(
                f"{c.effect.label()} (responses {d:.2f} standard errors apart)" for c, d in ties) +
                  ": the data cannot tell these apart, the best-scoring one is added")
        if runner:
            v += (f"; runner-up {runner.effect.label()} ({100 * runner.reduction:.0f} %, "
                  f"{evidence_strength(gap)} for the winner, IC gap {gap:.1f})")
        effects.append(win.effect)
        out = win.outputs
        if win.kind == "model":
            raw = win.raw if win.raw is not None else rp.simulate(inp, [*base, *effects], fit=True)
        if not _inside(_metrics(bench, out)):
            v += "; the model is still outside the band: no single effect explains all of it, iterating"
        it = Iteration(k, label, cost, metrics, where, ranked, win, runner, v, time.perf_counter() - ti)
        it.equivalent = [(c.effect.label(), d) for c, d in ties]
        iterations.append(it)
    else:
        verdict = f"stopped after {opts.max_iterations} iterations: " + iterations[-1].verdict
    t3 = time.perf_counter()
    after = sensorfx.apply(rp.simulate(inp, [*base, *effects]), bench.t, [*base, *effects]) if effects else before
    tm["final_simulation"] = time.perf_counter() - t3
    tm["identification"] = sum(it.seconds for it in iterations)
    tm["simulations"] = rp.simulations
    tm["total"] = time.perf_counter() - t0
    return Result(opts, bench, inp, rp, obj, reg, base, effects, before, after, iterations, verdict, tm)
