"""The batch's HTML summary: counts by verdict, one figure per metric against each swept parameter (one
colour per verdict; PNGs embedded, headless matplotlib), the table of failures and errors."""
from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

from .metrics import METRICS


def _num(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _figure(rows, param, metric) -> str | None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = {}
    for r in rows:
        x, y = _num(r.get(param)), _num(r.get(metric))
        if x is not None and y is not None:
            groups.setdefault(r["verdict"], []).append((x, y))
    if not groups:
        return None
    fig, ax = plt.subplots(figsize=(4.8, 3.2), dpi=90)
    for ver, colour in (("pass", "tab:green"), ("fail", "tab:red"), ("error", "tab:grey")):
        pts = groups.get(ver)
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", ms=4, color=colour, label=ver)
    m = METRICS[metric]
    ax.set_xlabel(param)
    ax.set_ylabel(f"{metric} [{m.unit}]")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_report(rows: list[dict], plan, params: list[str], path: Path) -> Path:
    e = html.escape
    count = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "fail", "error")}
    parts = [f"<!doctype html><meta charset='utf-8'><title>{e(plan.name)}</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}td,th{border:1px solid #ccc;padding:2px 6px;"
             "font-size:13px}table{border-collapse:collapse}img{margin:4px}td.why{white-space:pre-wrap}</style>",
             f"<h1>Batch {e(plan.name)}</h1><p>{e(plan.description)}</p>",
             f"<p>{len(rows)} runs: {count['pass']} pass, {count['fail']} fail, {count['error']} error</p>",
             "<h2>Metrics</h2><table><tr><th>metric</th><th>unit</th><th>definition</th></tr>"]
    parts += [f"<tr><td>{e(m)}</td><td>{e(METRICS[m].unit)}</td><td>{e(METRICS[m].doc)}</td></tr>" for m in plan.metrics]
    parts.append("</table><h2>Metrics against parameters</h2>")
    for p in params:
        imgs = [_figure(rows, p, m) for m in plan.metrics]
        imgs = [f"<img src='data:image/png;base64,{i}'>" for i in imgs if i]
        if imgs:
            parts.append(f"<h3>{e(p)}</h3>" + "".join(imgs))
    bad = [r for r in rows if r["verdict"] != "pass"]
    parts.append(f"<h2>Failures and errors ({len(bad)})</h2><table><tr><th>run</th><th>scenario</th><th>vehicle</th>"
                 + "".join(f"<th>{e(p)}</th>" for p in params) + "<th>seed</th><th>status</th><th>why</th></tr>")
    for r in bad:
        parts.append(f"<tr><td>{e(r['run_id'])}</td><td>{e(r['scenario'])}</td><td>{e(r['vehicle'])}</td>"
                     + "".join(f"<td>{e(str(r.get(p)))}</td>" for p in params)
                     + f"<td>{r['seed']}</td><td>{e(r['status'])}</td><td class='why'>{e(r['error'] or r['failed'])}</td></tr>")
    parts.append("</table>")
    path.write_text("\n".join(parts), encoding="utf-8", errors="backslashreplace")
    return path
