"""The verdict of a validation run, as an engineer reads it (the terminal summary, summary.json's `verdict`
and the head of report.html all show this one object):

1. what was found: the named effects with their values and 95 % intervals, or "no catalogue effect";
2. per compared channel, after the named effects and the nuisance adjustments: explained (by a named
   effect), structural (with the shape of what is left: offset, gain, lag or drift) or inside the band
   ("no band" with one run);
3. the candidates that were considered and not named, each with the reason the selection gave (its
   Candidate.note).

The sections cannot contradict each other: a channel is "explained" only by an effect named in section 1;
a structural shape describes what is left and is never called an effect (when a catalogue effect on that
channel was considered and turned down, the channel's line says so and section 3 says why); section 1 says
"no catalogue effect" exactly when nothing was named. `GLOSSARY` defines the terms the verdict uses.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from .data import MIN_RUNS, unit

#: the terms the verdict uses, defined where it is shown (report head, summary.json)
GLOSSARY = {
    "band": "the 95 % confidence interval of the mean of the runs (Student's t over the n runs): where the "
            "car's mean response lies; a model inside it cannot be told from the data",
    "catalogue effect": "an effect the model can switch on (tyre, brake, mass, grade, sensor bias, scale, "
                        "delay, ...), fitted by re-simulating the runs; named only when the data select it",
    "explained": "a channel that a named effect moves and that lies inside the band with it",
    "structural": "what differs between the model's structure and the car beyond every named effect; its "
                  "shape (offset, gain, lag or drift: the single form that fits most of the residual) describes "
                  "it, it is not an effect and nothing was added to the model for it",
    "nuisance adjustment": "small corrections fitted alongside every candidate and never named: each axle's "
                           "effective rolling radius (a scale of its wheel speeds) and a resistance offset "
                           "(acting only while the car moves); the per-channel lines are after them",
    "in the model's terms": "a value as the model reads it: the true value composed with what the model "
                            "reads in the same runs without it (its own lag beside a sensor delay, its own "
                            "offset beside a bias)",
    "95 % interval": "value +- half-width, from the runs one by one and the model error together",
}

SHAPES = ("offset", "gain", "lag", "drift")
SHOWN_PER_CHANNEL = 3         # candidates turned down named on a structural channel's line


@dataclass
class Found:
    effect: str                   # label
    name: str
    channel: str | None
    values: list[dict]            # {"parameter", "value", "half_width", "low", "high", "unit"}
    text: str


@dataclass
class ChannelLine:
    channel: str
    status: str                   # "explained" | "structural" | "inside the band" | "no band" (one run)
    text: str
    explained_by: list[str] = field(default_factory=list)
    shape: dict | None = None     # structural: {"kind", "value", "unit", "share"}
    considered: list[str] = field(default_factory=list)   # turned-down candidates acting on this channel
    inside_band: float | None = None


@dataclass
class TurnedDown:
    effect: str                   # label, at its fitted value
    name: str
    channel: str | None
    reason: str
    iteration: int
    text: str


@dataclass
class Verdict:
    headline: str                 # the first line: what was found
    found: list[Found]
    channels: list[ChannelLine]
    turned_down: list[TurnedDown]
    confounded: list[str]
    runs_used: list[str]
    left_out: list[dict]          # {"run", "reason"}
    min_runs: int
    notice: str                   # the report's top line when --min-runs lowered the minimum, else ""
    glossary: dict = field(default_factory=lambda: dict(GLOSSARY))

    def lines(self) -> list[str]:
        """The verdict as text lines: found, per channel, turned down, runs."""
        out = [self.headline]
        if self.channels:
            out.append("Per channel (after the named effects and the nuisance adjustments):")
            out += [f"  {c.text}" for c in self.channels]
        out.append("Considered and turned down:" if self.turned_down else "Considered and turned down: none")
        out += [f"  {t.text}" for t in self.turned_down]
        runs = f"Runs: {len(self.runs_used)} used"
        out.append(runs + (f", {len(self.left_out)} left out:" if self.left_out else ""))
        out += [f"  {d['run']}: {d['reason']}" for d in self.left_out]
        return out

    @property
    def text(self) -> str:
        return "\n".join(self.lines())

    def summary(self) -> dict:
        """summary.json's `verdict` (the runs are its `runs`: runs_summary)."""
        return {"headline": self.headline, "found": [asdict(f) for f in self.found],
                "channels": [asdict(c) for c in self.channels], "turned_down": [asdict(t) for t in self.turned_down],
                "confounded": self.confounded, "notice": self.notice, "glossary": self.glossary, "text": self.text}

    def runs_summary(self) -> dict:
        """summary.json's `runs`: the runs used, those left out with the reason, the minimum asked for."""
        return {"used": self.runs_used, "left_out": self.left_out, "min_runs": self.min_runs}


# ------------------------------------------------------------------------------------------ building
def _param_unit(effect, param: str, catalogue: dict) -> str:
    """The unit of an effect's parameter from the vehicle's catalogue (not in it: none; the value is kept)."""
    spec = catalogue.get(effect.name)
    u = next((p.unit for p in spec.params if p.name == param), "") if spec else ""
    if u.startswith("unit") and effect.channel:
        u = unit(effect.channel)
    return "" if u in ("1", "-") else u


def _g(x: float) -> str:
    return f"{x:.4g}"


def found(effect, catalogue: dict) -> Found:
    """An effect named, with its values and 95 % intervals (units from the vehicle's `catalogue`)."""
    vals, parts = [], []
    for k, v in effect.values().items():
        h = effect.uncertainty.get(k)
        u = _param_unit(effect, k, catalogue)
        us = f" {u}" if u else ""
        ok = h is not None and math.isfinite(h)
        vals.append({"parameter": k, "value": v, "half_width": h if ok else None,
                     "low": v - h if ok else None, "high": v + h if ok else None, "unit": u})
        parts.append(f"{k} = {_g(v)}{us}, 95 % interval {_g(v - h)} .. {_g(v + h)}{us}" if ok else
                     f"{k} = {_g(v)}{us} (no interval)")
    where = f" on {effect.channel}" if effect.channel else ""
    return Found(effect.label(), effect.name, effect.channel, vals, f"{effect.name}{where}: {'; '.join(parts)}")


def _turned_down(res, named_keys: set) -> list[TurnedDown]:
    """Every candidate of every iteration that was not named, at its latest fit, latest iteration first
    and in its ranking order."""
    seen: set = set()
    out = []
    for it in reversed(res.iterations):
        for c in it.candidates:
            key = c.effect.key
            if key in named_keys or key in seen:
                continue
            seen.add(key)
            reason = (c.note or "").strip().rstrip(".") or "not selected (the selection gave no reason)"
            lab = c.effect.label()
            out.append(TurnedDown(lab, c.effect.name, c.effect.channel, reason, it.index, f"{lab}: {reason}"))
    return out


def _acts_on(res, td: TurnedDown, channel: str) -> bool:
    if td.channel is not None:
        return td.channel == channel
    for it in res.iterations:
        for c in it.candidates:
            if c.effect.label() == td.effect and channel in (c.signature or []):
                return True
    return False


def _pct(x) -> str:
    return "no band" if x is None else f"{100 * x:.0f} % inside the band"


def build(res) -> Verdict:
    """The verdict of a workflow Result (see the module docstring)."""
    from .structural import describe_signature
    named = [found(e, res.profile.effects) for e in res.effects]
    labels = {f.effect for f in named}
    keys = {e.key for e in res.effects}
    down = _turned_down(res, keys)
    lines = []
    for c, d in (res.channels or {}).items():
        by = [b for b in d.get("explained_by", []) if b in labels]
        status = d.get("status")
        ib = d.get("inside_band")
        if ib is None:                     # one run: no band, nothing to judge inside or outside
            lines.append(ChannelLine(c, "no band", f"{c}: no band (one run): not judged"
                                     + (f"; moved by {' and '.join(by)}" if by else ""), by))
        elif status == "structural":
            sig = d.get("signature") or {"kind": "unshaped", "value": 0.0, "share": 0.0}
            shape = {"kind": sig.get("kind"), "value": sig.get("value"), "unit": unit(c), "share": sig.get("share")}
            considered = [t.effect for t in down if _acts_on(res, t, c)]
            considered.sort(key=lambda lab: 0 if f"[{c}]" in lab else 1)
            how = describe_signature(sig, unit(c))
            if sig.get("kind") in SHAPES:
                how = "shape " + how
            text = (f"{c}: structural, not a catalogue effect; {how}"
                    + (f"; moved in part by {' and '.join(by)}" if by else "")
                    + (f"; considered and turned down on this channel: {', '.join(considered[:SHOWN_PER_CHANNEL])}"
                       + (f" and {len(considered) - SHOWN_PER_CHANNEL} more" if len(considered) > SHOWN_PER_CHANNEL
                          else "") + " (reasons below)" if considered else "")
                    + f" ({_pct(ib)})")
            lines.append(ChannelLine(c, "structural", text, by, shape, considered, ib))
        elif by:
            lines.append(ChannelLine(c, "explained", f"{c}: explained by {' and '.join(by)} ({_pct(ib)})", by,
                                     inside_band=ib))
        else:
            lines.append(ChannelLine(c, "inside the band", f"{c}: inside the band ({_pct(ib)})", inside_band=ib))
    structural = [ln.channel for ln in lines if ln.status == "structural"]
    confounded = [f"{a} and {b} (correlation of their sensitivities {r:+.2f})" for a, b, r in res.confounded]
    if named:
        headline = "Found: " + "; ".join(f.text for f in named) + "."
        if confounded:
            headline += " The data cannot separate " + "; ".join(confounded) + "."
        if structural:
            headline += f" Structural, not a catalogue effect, on {', '.join(structural)} (see per channel)."
    else:
        headline = "Found: no catalogue effect."
        if structural:
            headline += (f" What is left on {', '.join(structural)} is structural (a difference in the model's "
                         f"structure, described by its shape below; no catalogue effect was selected for it).")
        elif lines and all(ln.status == "inside the band" for ln in lines):
            headline += " The model agrees with the data: every compared channel is inside the band."
        elif lines:
            headline += " One run: no band to judge the channels by."
    bench = res.bench
    min_runs = getattr(res.options, "min_runs", MIN_RUNS)
    notice = ""
    if min_runs < MIN_RUNS:
        notice = (f"Fewer runs allowed than the {MIN_RUNS} the data checks ask for (--min-runs {min_runs}): "
                  f"{bench.n} run(s) used" + (", no band (one run): nothing can be judged inside or outside it"
                                              if bench.n == 1 else ", the band of their mean is wide")
                  + "; read the verdict as weak.")
    return Verdict(headline, named, lines, down, confounded, [r.name for r in bench.runs],
                   [{"run": r.path.name, "reason": r.reason} for r in bench.rejected], min_runs, notice)


def contradictions(v: Verdict) -> list[str]:
    """What in `v` would contradict another section (empty for every verdict `build` makes)."""
    out = []
    labels = {f.effect for f in v.found}
    if bool(v.found) == v.headline.startswith("Found: no catalogue effect"):
        out.append("the first line and the effects found disagree")
    for c in v.channels:
        if c.status == "explained" and not c.explained_by:
            out.append(f"{c.channel} explained by no named effect")
        out += [f"{c.channel} explained by {b}, which was not named" for b in c.explained_by if b not in labels]
        if c.status != "structural" and "structural" in c.text:
            out.append(f"{c.channel} called structural with status {c.status}")
    out += [f"{t.effect} both named and turned down" for t in v.turned_down if t.effect in labels]
    low = v.text.lower()
    if "no catalogue effect explains" in low:
        out.append("says no catalogue effect explains what a channel's shape describes")
    return out
