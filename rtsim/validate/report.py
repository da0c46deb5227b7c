"""The report of a validation run: `DIR/report.html` with plots (PNG, matplotlib's headless Agg
backend) and `DIR/summary.json`:

    {"effects": [{"name", "parameters": {...}, "uncertainty": {...}, "model_error": {...}}, ...],  # as added
     "before": {channel: {"rms", "max", "inside_band"}}, "after": {...},
     "iterations": [{"iteration", "model_effects", "cost", "metrics", "where", "verdict", "winner",
                     "runner_up", "partners", "refitted", "joint", "candidates", "seconds"}, ...],
     "verdict": {"headline", "found", "channels", "turned_down", "confounded", "notice", "glossary", "text"},
     "runs": {"used": [names], "left_out": [{"run", "reason"}], "min_runs"},
     "accel_frame": "body" | "level", "channels": {channel: {"status", "text", "signature",
     "inside_band", "rms", "explained_by"}}, "nuisance": {name: {"value", "unit"}}, "correlations": [...], "confounded": [...]}

The verdict (rtsim.validate.verdict: what was found, per channel, the candidates turned down and why, the
terms it uses) heads report.html; when --min-runs lowered the minimum of runs, a notice stands above it.

rms and max are in the channel's SI unit; inside_band is the share of samples (0..1) inside the 95 %
band, null when there is no band (one run). Uncertainties are 95 % half-widths in the parameter's unit;
model_error is the part of it the residual left at the fit gives alone (the rest: the runs' scatter).
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .benchmark import LATERAL  # noqa: E402
from .data import unit  # noqa: E402
from .identify import evidence_strength  # noqa: E402
from .verdict import Verdict, build as build_verdict  # noqa: E402
from .workflow import Result  # noqa: E402


def _clean(x):
    """JSON-safe: NaN/inf -> None, numpy scalars -> float."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


#: how the model's accelerations were reported, per accelerometer frame (replay.level_frame)
FRAME_TEXT = {"body": "body (specific force in the body's axes, as rtsim's IMU measures it: it rolls and pitches "
                      "with the body and senses gravity's component)",
              "level": "level (the yaw-aligned horizontal frame: the model's body specific force rotated by its roll "
                       "and pitch, gravity not sensed; declared for these runs, as an inertial navigation system's "
                       "level-frame outputs)"}


def _values(effect) -> str:
    """An effect's fitted values with their 95 % half-widths, "name = value +- half; ..."."""
    return "; ".join(f"{k} = {v:.5g} +- {effect.uncertainty.get(k, float('nan')):.2g}"
                     for k, v in effect.values().items())


def _joint_row(d: dict) -> list:
    """A row of the joint fits tried (joint.joint_model's record)."""
    if "failed" in d:
        return ["", d["partner"], "", "", "", d["failed"], ""]

    def beyond(x: dict) -> str:
        return f"{100 * x['local_reduction']:.1f} % (IC {x['delta_ic']:+.1f})"
    both = d["winner_beyond"]["eligible"] and d["partner_beyond"]["eligible"]
    return [d["winner"], d["partner"], f"{d['correlation']:+.2f}", beyond(d["winner_beyond"]),
            beyond(d["partner_beyond"]), "yes" if both else "no", d["simulations"]]


def summary(res: Result, verdict: Verdict | None = None) -> dict:
    v = verdict or build_verdict(res)
    return _clean({
        "effects": [{"name": e.name, "parameters": dict(e.params), "uncertainty": dict(e.uncertainty),
                     "model_error": dict(e.model_error)} for e in res.effects],
        "before": res.metrics(res.before),
        "after": res.metrics(res.after),
        "iterations": [it.summary() for it in res.iterations],
        "verdict": v.summary(),
        "runs": v.runs_summary(),
        "accel_frame": res.accel_frame,
        "channels": {c: {k: v for k, v in d.items()} for c, d in res.channels.items()},
        "nuisance": {n: {"value": v, "unit": u} for n, (v, u) in res.nuisance.items()},
        "correlations": [{"effects": [a, b], "correlation": r} for a, b, r in res.correlations],
        "confounded": [[a, b] for a, b, _ in res.confounded],
    })


def displayed_adjustment(res: Result) -> dict:
    """The model's outputs after the nuisance adjustments, as plotted: a wheel speed is never carried
    across zero or moved off zero by them (a rolling radius scales a turning wheel, a resistance offset
    acts while the car moves: at standstill a wheel speed stays at rest), so a stopped wheel reads zero
    where the adjustment would push it past."""
    adj = res.objective.adjusted(res.after)
    out = dict(adj)
    for c in adj:
        if c.startswith("wheel_speed") and c in res.after:
            x, m = np.asarray(adj[c]), np.asarray(res.after[c])
            out[c] = np.where(np.sign(x) != np.sign(m), 0.0, x)
    return out


def _plot_channel(res: Result, c: str, path: Path) -> None:
    b = res.bench.bands[c]
    t = res.bench.t
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    for row in res.bench.values[c]:
        a1.plot(t, row, color="0.75", lw=0.4)
    if b.has_band:
        a1.fill_between(t, b.lower, b.upper, color="tab:blue", alpha=0.3, lw=0, label="95 % band of the mean")
    a1.plot(t, b.mean, color="tab:blue", lw=1.0, label=f"mean of {b.n} run(s)")
    a1.plot(t, res.before[c], color="tab:red", lw=0.9, label="model before")
    if res.effects:
        a1.plot(t, res.after[c], color="tab:green", lw=0.9, ls="--", label="model after")
    adj = displayed_adjustment(res)[c] if res.nuisance else None
    if adj is not None and np.allclose(adj, res.after[c], rtol=0.0, atol=1e-9 * (1.0 + float(np.max(np.abs(adj))))):
        adj = None                    # a channel the nuisance adjustments do not touch
    if adj is not None:
        a1.plot(t, adj, color="tab:purple", lw=0.8, ls=":", label="after, nuisance adjusted")
    a1.set_ylabel(f"{c} [{unit(c)}]")
    a1.legend(loc="best", fontsize=8)
    if b.has_band:
        a2.fill_between(t, -b.half, b.half, color="tab:blue", alpha=0.3, lw=0)
    a2.plot(t, res.before[c] - b.mean, color="tab:red", lw=0.7, label="residual before")
    if res.effects:
        a2.plot(t, res.after[c] - b.mean, color="tab:green", lw=0.7, label="residual after")
    if adj is not None:
        a2.plot(t, adj - b.mean, color="tab:purple", lw=0.7, ls=":", label="after, nuisance adjusted")
    a2.axhline(0.0, color="k", lw=0.5)
    a2.set_ylabel(f"model - mean [{unit(c)}]")
    a2.set_xlabel("time [s]")
    a2.legend(loc="best", fontsize=8)
    for p in res.regimes.phases:
        a2.axvline(p.start, color="0.6", lw=0.5, ls=":")
    _shade_steering(res, (a1, a2))
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _shade_steering(res: Result, axes) -> None:
    """Shade the stretches where the manoeuvre steers (residuals.STEER_ANGLE)."""
    st = res.regimes.steering
    if not st.any():
        return
    t = res.bench.t
    edges = np.flatnonzero(np.diff(np.concatenate([[0], st.astype(int), [0]])))
    for ax in axes:
        for k, (i0, i1) in enumerate(zip(edges[::2], edges[1::2])):
            ax.axvspan(t[i0], t[min(i1, t.size - 1)], color="tab:orange", alpha=0.08, lw=0,
                       label="steering" if k == 0 and ax is axes[0] else None)


def _plot_inputs(res: Result, path: Path) -> None:
    """The replayed inputs: runs, mean and band, and what the model's own sensors read of them (the
    steering-wheel angle after matching the steer-by-wire command, see replay)."""
    names = res.bench.inputs
    inp = res.inputs
    replayed = set(getattr(inp, "channels", ())) or {     # a two-wheeler's inputs name their channels
        c for c, x in (("brake_pressure", inp.brake), ("wheel_torque_rl", inp.torque_rl),
                       ("wheel_torque_rr", inp.torque_rr), ("throttle_angle", inp.throttle),
                       ("steering_wheel_angle", inp.steer)) if x is not None}
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 1.8 * len(names) + 0.6), sharex=True, squeeze=False)
    t = res.bench.t
    for ax, c in zip(axes[:, 0], names):
        b = res.bench.bands[c]
        for row in res.bench.values[c]:
            ax.plot(t, row, color="0.75", lw=0.4)
        if b.has_band:
            ax.fill_between(t, b.lower, b.upper, color="tab:blue", alpha=0.3, lw=0)
        ax.plot(t, b.mean, color="tab:blue", lw=1.0, label="mean")
        if c in res.before and c in replayed:
            ax.plot(t, res.before[c], color="tab:red", lw=0.7, ls="--", label="model (replayed)")
        ax.set_ylabel(f"{c}\n[{unit(c)}]", fontsize=8)
    axes[0, 0].legend(loc="best", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _table(rows: list[list], head: list[str]) -> str:
    h = "".join(f"<th>{html.escape(str(x))}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _fmt(x, spec=".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return format(x, spec)


def _pct(x) -> str:
    return "no band" if x is None else f"{100 * x:.1f} %"


def _verdict_html(res: Result, v: Verdict) -> list[str]:
    """The report's head: the notice (--min-runs lowered), the terms, the verdict's sections."""
    e = html.escape
    out = [f"<p class=notice><b>{e(v.notice)}</b></p>"] if v.notice else []
    out.append("<p class=terms><b>Terms.</b> " + " ".join(
        f"<i>{e(k)}</i>: {e(d)}." for k, d in v.glossary.items()) + "</p>")
    out.append(f"<h2>Verdict</h2><p class=verdict><b>{e(v.headline)}</b></p>")
    if v.channels:
        rows = [[c.channel, c.status, c.text.partition(": ")[2], _fmt(res.channels.get(c.channel, {}).get("rms")),
                 _pct(c.inside_band)] for c in v.channels]
        out.append("<h3>Per channel, after the named effects and the nuisance adjustments</h3>" + _table(
            rows, ["channel", "status", "what the model does there", "RMS (nuisance adjusted)", "inside band"]))
    if v.turned_down:
        rows = [[t.effect, t.iteration, t.reason] for t in v.turned_down]
        out.append("<h3>Considered and turned down</h3>" + _table(rows, ["candidate (fitted value)", "iteration",
                                                                         "why it was not named"]))
    else:
        out.append("<h3>Considered and turned down</h3><p>none</p>")
    left = "".join(f"<li>{e(d['run'])}: {e(d['reason'])}</li>" for d in v.left_out)
    out.append(f"<p><b>Runs:</b> {len(v.runs_used)} used" + (f"; left out:</p><ul>{left}</ul>" if left else ".</p>"))
    return out


def write_stopped(runs: dict, why: str, folder: Path) -> dict:
    """summary.json and report.html of a run the data checks stopped (data.require_runs): the runs used and
    left out with their reasons, and why it stopped."""
    folder.mkdir(parents=True, exist_ok=True)
    head = f"Stopped before any fit: {why}."
    lines = [head, f"Runs: {len(runs['used'])} used" + (f", {len(runs['left_out'])} left out:" if runs["left_out"]
                                                          else "")]
    lines += [f"  {d['run']}: {d['reason']}" for d in runs["left_out"]]
    summ = {"verdict": {"headline": head, "found": [], "channels": [], "turned_down": [], "confounded": [],
                        "notice": "", "text": "\n".join(lines)}, "runs": runs}
    (folder / "summary.json").write_text(json.dumps(summ, indent=2))
    e = html.escape
    left = "".join(f"<li>{e(d['run'])}: {e(d['reason'])}</li>" for d in runs["left_out"])
    (folder / "report.html").write_text(
        "<!doctype html><html><head><meta charset=utf-8><title>rtsim validate</title></head><body>"
        f"<h1>Validation stopped</h1><p><b>{e(head)}</b></p><p>Runs used: {e(', '.join(runs['used']) or 'none')}"
        f"</p><p>Left out:</p><ul>{left}</ul></body></html>")
    return summ


def write(res: Result, folder: Path) -> dict:
    """report.html, the plots and summary.json into `folder`; returns the summary."""
    folder.mkdir(parents=True, exist_ok=True)
    verdict = build_verdict(res)
    summ = summary(res, verdict)
    (folder / "summary.json").write_text(json.dumps(summ, indent=2))
    bench = res.bench
    plots = []
    _plot_inputs(res, folder / "inputs.png")
    for c in bench.compared:
        name = f"channel_{c}.png"
        _plot_channel(res, c, folder / name)
        plots.append((c, name))
    cat = res.profile.effects
    e = html.escape
    parts = [f"<h1>Validation report: {e(res.options.vehicle.name)}</h1>", *_verdict_html(res, verdict),
             f"<p>Accelerations compared in the {e(res.accel_frame)} frame (see Model and replay).</p>"]
    # identified effects
    if res.effects:
        rows = []
        for eff in res.effects:
            spec = cat.get(eff.name)
            for k, v in eff.values().items():
                u = eff.uncertainty.get(k)
                pu = next((p.unit for p in spec.params if p.name == k), "") if spec else ""
                if pu.startswith("unit") and eff.channel:
                    pu = unit(eff.channel)
                rows.append([eff.name, eff.channel or "", k, f"{v:.5g}", _fmt(u, ".2g"),
                             _fmt(eff.model_error.get(k), ".2g"), pu])
        parts.append("<h2>Effects added to the model (in order)</h2>" +
                     _table(rows, ["effect", "channel", "parameter", "value", "+- 95 %",
                                   "of which the model error alone", "unit"]) +
                     "<p>The interval combines the runs' scatter with the model error: the residual the fit "
                     "leaves (structural mismatch included) as correlated noise, the spread of the value over "
                     "the channels' time segments, and the change of the value that residual could cause. "
                     "A sensor effect's value is in the model's terms: a structural mismatch of the model "
                     "with the same signature on that channel (a lag of its own response beside a delay, a "
                     "constant offset beside a bias) reads as part of it and leaves no residual to widen the "
                     "interval with.</p>")
    else:
        parts.append("<h2>Effects added to the model</h2><p>none</p>")
    # before / after
    mb, ma = summ["before"], summ["after"]
    rows = [[c, unit(c), _fmt(mb[c]["rms"]), _fmt(ma[c]["rms"]),
             _fmt(mb[c]["rms"] / ma[c]["rms"] if ma[c]["rms"] else None, ".2f"), _fmt(mb[c]["max"]), _fmt(ma[c]["max"]),
             _pct(mb[c]["inside_band"]), _pct(ma[c]["inside_band"])] for c in bench.compared]
    parts.append("<h2>Gap before and after</h2>" + _table(rows, ["channel", "unit", "RMS before", "RMS after",
                                                                 "ratio", "max before", "max after",
                                                                 "inside band before", "inside band after"]))
    if res.comparison:
        parts.append(f"<p>Model outputs: {e(res.comparison)}.</p>")
    if res.nuisance:
        rows = [[n, f"{v:.4g}", u] for n, (v, u) in res.nuisance.items()]
        parts.append("<h3>Nuisance adjustments (fitted alongside, never named as an effect)</h3>" +
                     _table(rows, ["adjustment", "value", "unit"]))
    if res.correlations:
        rows = [[a, b, f"{r:+.2f}", "yes" if abs(r) >= 0.9 else "no"] for a, b, r in res.correlations]
        parts.append("<h3>Correlation of the identified effects</h3>" +
                     _table(rows, ["effect", "effect", "correlation of sensitivities", "confounded"]))
    if res.mean_input and res.mean_input.get("before") is not res.before:
        mi = {k: res.metrics(v) for k, v in res.mean_input.items()}
        rows = [[c, unit(c), _fmt(mi["before"][c]["rms"]), _fmt(mi["after"][c]["rms"]), _pct(mi["before"][c]["inside_band"]),
                 _pct(mi["after"][c]["inside_band"])] for c in bench.compared]
        parts.append("<h3>The same with the mean inputs replayed once</h3>" + _table(
            rows, ["channel", "unit", "RMS before", "RMS after", "inside band before", "inside band after"]))
    # iterations
    parts.append("<h2>Iterations</h2>")
    for it in res.iterations:
        parts.append(f"<h3>Iteration {it.index}: model {e(', '.join(it.model) or 'as configured')}</h3>")
        parts.append(f"<p>normalised cost {it.cost:.3g} (about 1 = within the data's own uncertainty).</p>")
        parts.append("<p><b>Where the model leaves the band</b></p><ul>" +
                     "".join(f"<li>{e(w)}</li>" for w in it.where) + "</ul>")
        parts.append(f"<p><b>Outcome.</b> {e(it.verdict)}</p>")
        if it.winner:
            w = it.winner
            spec = cat.get(w.effect.name)
            bych = ", ".join(f"{c} {m:.2f}" for c, m in w.match_by_channel.items())
            vals = _values(w.effect)
            parts.append("<p><b>Evidence for " + e(w.effect.label()) + ":</b> " + e(
                f"fitted {vals} (95 %); removes {100 * w.reduction:.1f} % of the disagreement; information "
                f"criterion {w.delta_ic:+.1f}; its signature ({spec.signature if spec else ''}) matches the "
                f"residual with cosine {w.match:.2f} (by channel: {bych})") + "</p>")
            for p in it.partners:
                vals = _values(p.effect)
                parts.append("<p><b>Added jointly with it: " + e(p.effect.label()) + ".</b> " + e(
                    f"fitted together with the winner, {vals} (95 %, joint interval); beyond the winner it removes "
                    f"{100 * p.local_reduction:.1f} % of the disagreement on its channels ({', '.join(p.signature)}), "
                    f"information criterion {p.delta_ic:+.1f}") + "</p>")
            if it.refitted:
                parts.append("<p><b>Re-fitted jointly with it:</b> " + e(", ".join(
                    f"{a} -> {b}" for a, b in it.refitted)) + "</p>")
            if it.joint.get("tried"):
                rows = [_joint_row(d) for d in it.joint["tried"]]
                parts.append("<p><b>Joint fits tried</b> (each member judged beyond the other on its own "
                             "channels)</p>" + _table(rows, ["winner (joint value)", "partner (joint value)",
                                                             "correlation of sensitivities", "winner beyond the partner",
                                                             "partner beyond the winner", "both eligible",
                                                             "simulations"]))
            if it.runner_up:
                r = it.runner_up
                parts.append("<p><b>Runner-up:</b> " + e(
                    f"{r.effect.label()}, removes {100 * r.reduction:.1f} %, IC {r.delta_ic:+.1f}; "
                    f"{evidence_strength(r.ic - w.ic)} for the winner" + (f" ({r.note})" if r.note else "")) + "</p>")
        if it.candidates:
            rows = []
            for c in it.candidates[:25]:
                vals = ", ".join(f"{k} = {v:.4g} +- {c.effect.uncertainty.get(k, float('nan')):.2g}"
                                 for k, v in c.effect.values().items())
                rows.append([c.effect.name, c.effect.channel or "", vals, f"{100 * c.reduction:.1f} %",
                             f"{c.delta_ic:+.1f}", f"{c.match:.2f}", c.sims, "yes" if c.eligible else "no", c.note])
            parts.append(_table(rows, ["candidate", "channel", "fitted value (95 %)", "removes", "delta IC",
                                       "signature match", "simulations", "eligible", "note"]))
    # config
    if res.config_path:
        parts.append(f"<h2>New vehicle config</h2><p>{e(str(res.config_path))} (the original is untouched)</p>"
                     f"<pre>{e(res.diff)}</pre>")
    # plots
    parts.append("<h2>Channels</h2><p>grey: runs; blue: mean and 95 % band; red: model before; green dashed: "
                 "after; purple dotted: after with the nuisance adjustments."
                 " Lower panels: residual (model - mean) and the band's half-width; dotted lines: phase "
                 "boundaries" + ("; orange: the manoeuvre steers" if res.regimes.steering.any() else "") + ".</p>")
    parts.extend(f'<h3>{e(c)}</h3><img src="{e(n)}" alt="{e(c)}">' for c, n in plots)
    # data
    al = bench.alignment
    rows = [[r.name, f"{o:.4f}", _fmt(al.correlation[i] if al.correlation else None, ".4f"), f"{r.rate:.0f}",
             f"{r.duration:.2f}", "; ".join(r.notes)] for i, (r, o) in enumerate(zip(bench.runs, al.offsets))]
    parts.append("<h2>Benchmark data</h2>"
                 f"<p>{bench.n} run(s) used; grid {1 / bench.dt:g} Hz over {bench.t[-1]:.2f} s; alignment: "
                 f"{e(al.method)}.</p>" +
                 _table(rows, ["run", "time at grid 0 [s]", "input correlation", "rate [Hz]", "duration [s]", "notes"]))
    if bench.rejected:
        parts.append("<p><b>Left out:</b></p><ul>" + "".join(f"<li>{e(r.path.name)}: {e(r.reason)}</li>"
                                                            for r in bench.rejected) + "</ul>")
    if bench.notes:
        parts.append("<ul>" + "".join(f"<li>{e(n)}</li>" for n in bench.notes) + "</ul>")
    rows = [[c, unit(c), _fmt(v["range"]), _fmt(v["rms_spread"]), _fmt(v["max_spread"]),
             _pct(v["relative"]) if v["relative"] == v["relative"] else "-"] for c, v in bench.repeatability.items()]
    parts.append("<p><b>Repeatability of the inputs</b> (run-to-run standard deviation)</p>" +
                 _table(rows, ["input", "unit", "range", "RMS spread", "max spread", "RMS spread / range"]))
    parts.append('<img src="inputs.png" alt="inputs">')
    base = ("config effects: " + ", ".join(x.label() for x in res.base_effects) if res.base_effects
            else "no effects in the config")
    kind = ("lateral (steering: " + ", ".join(c for c in bench.compared if c in LATERAL) + " compared)"
            if bench.lateral else "longitudinal (no steering: lateral channels not compared)")
    if res.profile.manoeuvre:                   # the vehicle's own description (its validation profile)
        kind = res.profile.manoeuvre.format(compared=", ".join(bench.compared))
    steer = ""
    err = res.inputs.steer_error.get(res.replayer.dt)
    if err is not None and math.isfinite(err):
        lead = res.inputs.steer_lead.get(res.replayer.dt, 0) * bench.dt
        steer = (f"; steering-wheel command matched so that the model's angle follows the measured one within "
                 f"{err:.2g} rad RMS (loop delay {lead * 1e3:.0f} ms)")
    parts.append(f"<h2>Model and replay</h2><p>manoeuvre: {e(kind)}; vehicle {e(str(res.options.vehicle))}, road "
                 f"{e(str(res.replayer.road_path))}, step {res.replayer.dt * 1e3:g} ms (fits at "
                 f"{res.replayer.fit_step(bench.dt) * 1e3:g} ms); inputs replayed: {e(res.inputs.mode)}; "
                 f"start speed {res.inputs.speed0:.3g} m/s{e(steer)}; {e(base)}.</p>")
    parts.append(f"<p>Accelerometer frame: {e(FRAME_TEXT[res.accel_frame])}.</p>")
    timing = ", ".join(f"{k} {v:.1f} s" if isinstance(v, float) else f"{k} {v}" for k, v in res.timings.items())
    parts.append(f"<p>Timing: {e(timing)}</p>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse;font-size:90%}"
             "td,th{border:1px solid #bbb;padding:2px 6px}.verdict{background:#eef;padding:6px}"
             ".notice{background:#fec;padding:6px}.terms{font-size:85%;color:#333}"
             "img{max-width:100%}pre{background:#f6f6f6;padding:6px;overflow-x:auto}")
    (folder / "report.html").write_text(f"<!doctype html><html><head><meta charset=utf-8><title>rtsim validate"
                                        f"</title><style>{style}</style></head><body>{''.join(parts)}</body></html>")
    return summ
