"""What the catalogue explains and what it cannot: per compared channel, after the identified effects and
the nuisance adjustments (objective.Nuisance), one of

- "inside the band": at least `INSIDE` of the samples inside the 95 % band and, when an identified
  effect moves the channel (its signature channels, identify.channel_evidence), "explained by X";
- "structural, not in the catalogue": what is left has a shape no catalogue effect gave; its signature
  is the one of four single regressors that explains most of the residual (least squares): `offset`
  (a constant, unit of the channel), `gain` (the model's own signal, relative), `lag` (the model's
  time derivative: a positive value means the model lags the car's channel, s) or `drift` (a ramp
  in time, unit/s), with the share of the residual it explains; below `SHAPED` share: "unshaped".
  An identified effect that moves such a channel is said to explain it in part.
"""
from __future__ import annotations

import numpy as np

from .stats import error_metrics

INSIDE = 0.9
SHAPED = 0.3


def signature(t: np.ndarray, model: np.ndarray, residual: np.ndarray) -> dict:
    """The single regressor (offset, gain, lag, drift) that explains most of `residual` (model - mean)."""
    rr = float(residual @ residual)
    if rr <= 0.0:
        return {"kind": "none", "value": 0.0, "share": 0.0}
    regs = {"offset": np.ones_like(model), "gain": model, "lag": -np.gradient(model, t),
            "drift": t - t.mean()}
    best = {"kind": "unshaped", "value": 0.0, "share": 0.0}
    for kind, x in regs.items():
        xx = float(x @ x)
        if xx <= 0.0:
            continue
        # the model minus the regressor's share is the car: residual = coef * x
        coef = float(x @ residual) / xx
        share = 1.0 - float(np.sum((residual - coef * x) ** 2)) / rr
        if share > best["share"]:
            best = {"kind": kind, "value": coef, "share": share}
    if best["share"] < SHAPED:
        best["kind"] = "unshaped"
    return best


def describe_signature(sig: dict, unit: str) -> str:
    k, v = sig["kind"], sig["value"]
    if k == "offset":
        text = f"offset: the model reads {v:+.3g} {unit} more"
    elif k == "gain":
        text = f"gain: the model's signal is {100 * abs(v):.1f} % {'larger' if v >= 0 else 'smaller'}"
    elif k == "lag":
        # residual = -v model' : the car's mean = model + v model' = model(t + v), the model v behind it
        text = f"lag: the model lags the car's signal by {1e3 * v:.0f} ms" if v > 0 else \
            f"lead: the model leads the car's signal by {-1e3 * v:.0f} ms"
    elif k == "drift":
        text = f"drift: the model drifts by {v:+.3g} {unit}/s"
    else:
        return "no simple shape (offset, gain, lag or drift) explains it"
    return f"{text} ({100 * sig['share']:.0f} % of the residual)"


def channel_report(bench, objective, outputs: dict, explained: dict[str, list[str]], units: dict) -> dict:
    """channel -> {"status", "text", "signature", "inside_band", "rms"} for the model `outputs` (the
    effects in, the nuisance adjustments applied by the objective); `explained`: channel -> labels of the
    identified effects whose signature names it."""
    adjusted = objective.adjusted(outputs)
    out = {}
    for c in bench.compared:
        b = bench.bands[c]
        m = error_metrics(adjusted[c], b)
        by = explained.get(c, [])
        inside = m["inside_band"] is not None and m["inside_band"] >= INSIDE
        sig = signature(bench.t, adjusted[c], adjusted[c] - b.mean)
        if inside:
            status = "explained" if by else "inside the band"
            text = ("explained by " + " and ".join(by)) if by else "inside the band"
        else:
            status = "structural"
            text = ("structural, not in the catalogue; " + describe_signature(sig, units.get(c, ""))
                    + ("; in part explained by " + " and ".join(by) if by else ""))
        out[c] = {"status": status, "text": text, "signature": sig, "inside_band": m["inside_band"],
                  "rms": m["rms"], "explained_by": by}
    return out


def correlations(cands: list) -> list[tuple[str, str, float]]:
    """Correlation (cosine) of the identified effects' sensitivities: near +-1, the data cannot separate them."""
    out = []
    for i, a in enumerate(cands):
        for b in cands[i + 1:]:
            if a.J is None or b.J is None:
                continue
            na, nb = float(np.linalg.norm(a.J)), float(np.linalg.norm(b.J))
            if na > 0 and nb > 0:
                out.append((a.effect.label(), b.effect.label(), float(a.J @ b.J) / (na * nb)))
    return out
