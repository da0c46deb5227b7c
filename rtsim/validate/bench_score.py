"""Scoring the field benchmark: each case's outcome from the named effects against the generator's truth
(rtsim.validate.bench_truth), and the set's rates.

Per case (named: the workflow's identified effects; hidden: the case's catalogue effects):
- "right": the named effects are exactly the hidden ones (effect and channel), each value within
  `TOL` of its value in the model's terms (sensor effects 10 %, model effects 20 %);
- "value off": the right effects, a value outside its tolerance;
- "false": an effect named that was not hidden (none, outside and small cases included);
- "missed": something hidden, nothing (or only part of it) named, nothing false;
- "error": the workflow stopped with an error (never right, whatever was hidden).
Rates: named right = "right" among the cases whose every effect is larger than the structural mismatch,
separable from every other catalogue effect and reproducible by the model's own version of it (bench_truth;
the bar's denominator); named right among the larger and separable cases (the definition before
reproducibility) and among the larger cases alone (before separability), reported beside it;
value error = per hidden effect named, |named - truth| / |truth| (within tolerance: its share);
false naming = share of all cases with a "false" naming; none-cases named = none and outside cases
with any named effect; "cannot be told apart" = share of cases whose verdict says so.
"""
from __future__ import annotations

from collections import Counter

TOL = {"sensor": 0.10, "model": 0.20}
TOLD_APART = "cannot be told apart"


def _key(effect: str, channel: str | None) -> str:
    return f"{effect}[{channel}]" if channel else effect


def outcome(case: dict, truth: dict, named: list[dict], verdict: str, error: str | None = None) -> dict:
    """The case's outcome (module docstring). named: [{"effect", "channel", "params": {param: value}}];
    error: the workflow's error message, if it stopped with one."""
    hidden = {_key(e["effect"], e["channel"]): e for e in truth["effects"]}
    found = {_key(n["effect"], n.get("channel")): n for n in named}
    errors = {}
    for k, e in hidden.items():
        if k in found:
            value = found[k]["params"].get(e["param"])
            ref = e["model_terms"]
            errors[k] = abs(value - ref) / abs(ref) if value is not None and ref else float("inf")
    extra = sorted(set(found) - set(hidden))
    if error:
        status = "error"
    elif extra:
        status = "false"
    elif set(found) == set(hidden) and hidden:
        status = "right" if all(errors[k] <= TOL[hidden[k]["kind"]] for k in hidden) else "value off"
    elif not hidden:
        status = "right"                    # nothing hidden, nothing named
    else:
        status = "missed"
    return {"id": case["id"], "kind": case["kind"], "sim": case["sim"], "tyre": case["tyre"],
            "larger": truth["larger"], "separable": truth["separable"],
            "reproducible": truth.get("reproducible", True), "status": status,
            "hidden": sorted(hidden), "named": sorted(found),
            "extra": extra, "errors": errors,
            "within": {k: errors[k] <= TOL[hidden[k]["kind"]] for k in errors},
            "told_apart": TOLD_APART in verdict.lower()}


def rates(outcomes: list[dict]) -> dict:
    """The set's rates (module docstring), with the counts behind them."""
    def share(k, n):
        return {"share": k / n if n else float("nan"), "count": k, "of": n}
    larger = [o for o in outcomes if o["kind"] in ("one", "two") and o["larger"]]
    separable = [o for o in larger if o["separable"]]
    judged = [o for o in separable if o["reproducible"]]
    errs = [(k, e, o["within"][k]) for o in outcomes for k, e in o["errors"].items()]
    blank = [o for o in outcomes if o["kind"] in ("none", "outside")]
    return {
        "cases": len(outcomes),
        "named_right": share(sum(o["status"] == "right" for o in judged), len(judged)),
        "named_right_separable": share(sum(o["status"] == "right" for o in separable), len(separable)),
        "named_right_larger": share(sum(o["status"] == "right" for o in larger), len(larger)),
        "inseparable_told_apart": share(sum(o["told_apart"] and not o["named"] for o in larger if not o["separable"]),
                                        len(larger) - len(separable)),
        "value_within_tolerance": share(sum(w for *_, w in errs), len(errs)),
        "value_error_median": sorted(e for _, e, _ in errs)[len(errs) // 2] if errs else float("nan"),
        "false_naming": share(sum(o["status"] == "false" for o in outcomes), len(outcomes)),
        "none_cases_named": share(sum(bool(o["named"]) for o in blank), len(blank)),
        "cannot_be_told_apart": share(sum(o["told_apart"] for o in outcomes), len(outcomes)),
        "status": dict(Counter(o["status"] for o in outcomes)),
    }


def confusion(outcomes: list[dict]) -> dict[str, Counter]:
    """hidden effect[channel] (or "none" / "outside") -> Counter of what was named for it: the same effect, another
    one, or "nothing". A hidden effect counts its own name when named, and each effect named in its case that
    was not hidden; "nothing" when neither."""
    rows: dict[str, Counter] = {}
    for o in outcomes:
        hidden = o["hidden"] or [o["kind"]]
        for h in hidden:
            row = rows.setdefault(h, Counter())
            if h in o["named"]:
                row[h] += 1
            for x in o["extra"]:
                row[x] += 1
            if h not in o["named"] and not o["extra"]:
                row["nothing"] += 1
    return rows


def acceptable(rec: dict, truth: dict) -> tuple[bool, str]:
    """Whether a case's outcome meets the bar, and why not: the workflow ran; nothing named that was not hidden; every
    hidden effect larger than the structural mismatch, separable from the other catalogue effects and reproducible
    by the model's own version of it named within its tolerance; a smaller, inseparable or irreproducible one
    either not named or named within its tolerance (it may be told apart or not)."""
    if rec["status"] == "error":
        return False, "the workflow stopped with an error"
    if rec["extra"]:
        return False, f"named {', '.join(rec['extra'])}, not hidden"
    for e in truth["effects"]:
        k = _key(e["effect"], e["channel"])
        if k in rec["errors"]:
            if not rec["within"][k]:
                return False, (f"{k} named {100 * rec['errors'][k]:.1f} % off its value in the model's terms "
                               f"{e['model_terms']:.4g}")
        elif e["larger"] and e["separable"] and e.get("reproducible", True):
            return False, f"{k} not named (its effect is {e['ratio']:.1f} times the structural mismatch)"
    return True, ""
