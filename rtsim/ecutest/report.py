"""The reports of a catalogue run: a JUnit XML file (written by junitparser, which CI tools read), the results
table on the terminal, and an HTML page with each case's plots around its events (matplotlib figures drawn
by the worker that ran the case, embedded in the page so it is one self-contained file)."""
from __future__ import annotations

import base64
import html
import math
from pathlib import Path

PLOT_MARGIN = 0.5          # s shown before the event and after the judged window


def plot_case(sig, case, outcomes, path: Path) -> Path:
    """One PNG per case: a panel per expectation, its signal around the event (event line, judged window
    shaded, bounds or threshold, the deciding sample marked; every fault onset and end of the case as
    thin lines)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .catalog import parse_condition

    n = len(outcomes)
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.3 * n), squeeze=False)
    for ax, e, o in zip(axes[:, 0], case.expect, outcomes):
        lo, hi = o.window
        if not (math.isfinite(lo) and math.isfinite(hi)):
            lo, hi = 0.0, sig.end
        a, b = max(0.0, lo - PLOT_MARGIN), min(sig.end, hi + PLOT_MARGIN)
        if o.signal in sig.series:
            t, v = sig.series[o.signal]
            m = (t >= a) & (t <= b)
            ax.plot(t[m], v[m], lw=1.0, drawstyle="steps-post" if o.signal.startswith(("fault.", "sim.", "commands.", "ecu.")) else "default")
        for te, fid, ev in sig.fault_events:
            if a <= te <= b:
                ax.axvline(te, color="red" if ev == "onset" else "grey", lw=0.6, ls=":")
        ax.axvspan(lo, hi, color="tab:green" if o.passed else "tab:red", alpha=0.08)
        if o.event_time is not None:
            ax.axvline(o.event_time, color="k", lw=0.8)
        for lim in (getattr(e, "min", None), getattr(e, "max", None)):
            if lim is not None:
                ax.axhline(lim, color="tab:orange", lw=0.8, ls="--")
        if getattr(e, "condition", None):
            ax.axhline(parse_condition(e.condition, signal=False)[2], color="tab:orange", lw=0.8, ls="--")
        if o.time is not None and o.value is not None:
            ax.plot([o.time], [o.value], "o", ms=5, color="tab:green" if o.passed else "tab:red")
        ax.set_title(f"{'PASS' if o.passed else 'FAIL'}  {o.label}  (after {o.event})", fontsize=9, loc="left")
        ax.set_xlabel("simulated time, s", fontsize=8)
        ax.set_ylabel(o.signal, fontsize=7)
        ax.tick_params(labelsize=7)
        ax.set_xlim(a, b if b > a else a + 1.0)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def write_junit(name: str, rows: list[dict], path: Path) -> Path:
    """The JUnit XML of the rows (one testcase per case, classname the catalogue): a failed case carries a
    <failure> whose message names each failed expectation, its time and observed value; a case that could
    not be judged an <error>; each expectation's text in system-out."""
    from junitparser import Error, Failure, JUnitXml, TestCase, TestSuite

    suite = TestSuite(name)
    for r in rows:
        tc = TestCase(r["name"], classname=name, time=round(float(r.get("wall_s") or 0.0), 3))
        if r["status"] == "failed":
            tc.result = [Failure(r["message"], "expectation")]
        elif r["status"] == "error":
            tc.result = [Error(r["message"], "error")]
        lines = [("PASS " if o["passed"] else "FAIL ") + o["message"] for o in (r.get("outcomes") or [])]
        if lines:
            tc.system_out = "\n".join(lines)
        suite.add_testcase(tc)
    suite.update_statistics()
    xml = JUnitXml()
    xml.add_testsuite(suite)
    xml.write(str(path), pretty=True)
    return path


def table(rows: list[dict]) -> str:
    """The results table (plain text): case, status, simulated end, wall time, and the first failure."""
    head = f"{'case':<32} {'status':<7} {'sim s':>6} {'wall s':>7}  message"
    out = [head, "-" * len(head)]
    for r in rows:
        msg = (r.get("message") or "").split(" | ")[0]
        sim = r.get("sim_end")
        out.append(f"{r['name']:<32} {r['status']:<7} {'' if sim is None else f'{sim:.2f}':>6} "
                   f"{float(r.get('wall_s') or 0):>7.1f}  {msg}")
    counts = {s: sum(r["status"] == s for r in rows) for s in ("passed", "failed", "error")}
    out.append(f"{len(rows)} cases: {counts['passed']} passed, {counts['failed']} failed, {counts['error']} errors")
    return "\n".join(out)


def write_html(cat, rows: list[dict], out: Path, path: Path) -> Path:
    """The HTML report: the summary, then per case its description, each expectation's verdict and message,
    and its plots (embedded PNG)."""
    esc = html.escape
    counts = {s: sum(r["status"] == s for r in rows) for s in ("passed", "failed", "error")}
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>", esc(cat.spec.name), "</title><style>",
             "body{font-family:sans-serif;max-width:60em;margin:auto} .passed{color:#070} .failed{color:#b00} "
             ".error{color:#a50} td,th{padding:2px 8px;text-align:left} img{max-width:100%}</style></head><body>",
             f"<h1>ECU tests: {esc(cat.spec.name)}</h1><p>{esc(cat.spec.description)}</p>",
             f"<p>{len(rows)} cases: {counts['passed']} passed, {counts['failed']} failed, {counts['error']} errors; "
             f"mode {esc(cat.spec.mode)}</p><table><tr><th>case</th><th>status</th><th>message</th></tr>"]
    for r in rows:
        parts.append(f"<tr><td><a href='#{esc(r['name'])}'>{esc(r['name'])}</a></td><td class='{r['status']}'>"
                     f"{r['status']}</td><td>{esc((r.get('message') or '').split(' | ')[0])}</td></tr>")
    parts.append("</table>")
    by_name = {c.name: c for c in cat.spec.cases}
    for r in rows:
        case = by_name.get(r["name"])
        parts.append(f"<h2 id='{esc(r['name'])}'>{esc(r['name'])} <span class='{r['status']}'>{r['status']}</span></h2>")
        if case is not None and case.description:
            parts.append(f"<p>{esc(case.description)}</p>")
        if r["status"] == "error":
            parts.append(f"<p class='error'>{esc(r.get('message') or '')}</p>")
        parts.append("<ul>")
        for o in r.get("outcomes") or []:
            cls = "passed" if o["passed"] else "failed"
            parts.append(f"<li class='{cls}'>{'PASS' if o['passed'] else 'FAIL'}: {esc(o['message'])}</li>")
        parts.append("</ul>")
        png = out / "cases" / r["name"] / "plot.png"
        if png.exists():
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            parts.append(f"<img alt='plots of {esc(r['name'])}' src='data:image/png;base64,{data}'>")
    parts.append("</body></html>")
    path.write_text("".join(parts), encoding="utf-8")
    return path
