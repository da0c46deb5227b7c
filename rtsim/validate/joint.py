"""Several model effects at once (issue 15): a model winner fitted jointly with the model candidates that
promise to explain what it leaves, and with the model effects added in earlier iterations, so that a first
effect that absorbed part of a second is corrected (identify.fit_joint does the fit; this module chooses
the partners, judges each member beyond the others and combines the runs' estimates)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtsim.errors import RtsimError

from .identify import (CLEAR, LITTLE, MIN_SIZE, Candidate, Context, JointFit, Member, combine_runs,
                       joint_member)
from .tasks import Failed, map_tasks

JOINT_TOP = 2                # model effects tried jointly with a model winner
JOINT_PROMISE = 0.1          # share of the winner's remaining cost a partner must be predicted to remove (linearised)
JOINT_SIZE = 0.5             # and the share of MIN_SIZE it must be predicted to move the outputs by (RMS)


@dataclass
class JointOutcome:
    """The outcome of joint_model: the members' candidates at their final (per-run) values, in the fit's
    order (earlier effects, the winner, the partner), the partner (None: a re-fit only), the outputs."""
    members: list[Candidate]
    partner: Candidate | None
    refitted: list[Candidate]
    outputs: dict
    raw: dict
    fit: JointFit
    text: str
    info: dict


def near_off(ctx: Context, cand: Candidate) -> np.ndarray:
    """A model candidate's sensitivity near its off value, where a joint fit starts it: the secant from
    the model as it stands to the candidate's simulated point nearest the off value (its single-fit
    secant sits where it was pushed to carry the winner's part too, on a bound at worst)."""
    pts = [(th, raw) for th, raw in cand.points if th != 0.0 and raw]
    if not pts:
        return cand.J
    th, raw = min(pts, key=lambda p: abs(p[0]))
    obj = ctx.objective
    r = obj.residual(ctx.replayer.reported(raw, ctx.inputs.t, ctx.effects))
    return (r - obj.residual(ctx.outputs)) / th


def promise(ctx: Context, win: Candidate, cols: list[np.ndarray], j: np.ndarray) -> tuple[float, float]:
    """The share of the winner's remaining cost an effect of sensitivity `j` would remove on top of it
    and how far it would move the outputs (RMS, standard errors), linearised: `j` made orthogonal to
    the columns of the effects refitted with it."""
    r = ctx.objective.residual(win.outputs)
    j = np.array(j, dtype=float)
    for c in cols:
        cc = float(c @ c)
        if cc > 0:
            j -= (float(c @ j) / cc) * c
    jj, rr = float(j @ j), float(r @ r)
    if not (jj > 0 and rr > 0):
        return 0.0, 0.0
    return float(j @ r) ** 2 / jj / rr, abs(float(j @ r)) / math.sqrt(jj * r.size)


def joint_model(ctx: Context, win: Candidate, ranked: list[Candidate], earlier: list[Candidate],
                 workers, progress, info: dict) -> JointOutcome | None:
    """Several model effects at once. The model winner `win` (its value from the runs, its outputs in
    hand) is fitted jointly (identify.fit_joint) with the model effects added in earlier iterations
    (`earlier`: a first effect that absorbed part of a second is corrected) and, in turn, with the
    `JOINT_TOP` model candidates predicted to remove at least `JOINT_PROMISE` of what the winner leaves
    and to move the outputs by `JOINT_SIZE` of the size an eligible effect needs (linearised, from their
    sensitivities near the off value, near_off: nothing is simulated when none qualifies, nor when the
    winner brings every channel within the data's own uncertainty, the loop's stop). A
    partner is added when each of the two is eligible beyond the other (identify.joint_member: the joint
    fit judged against the partner's own single fit for the winner and against the winner's (re-)fit for
    the partner, on their signature channels, information criterion included) and both values clear the
    off value by `CLEAR` half-widths of their joint intervals from the runs one by one. What was tried
    goes to `info` (the iteration's `joint`)."""
    bench, rp = ctx.bench, ctx.replayer
    keys = {c.effect.key for c in earlier}
    fixed = [e for e in ctx.effects if not (e.kind == "model" and e.key in keys)]
    base = [Member.of(c) for c in [*earlier, win]]
    cols = [m.J for m in base]
    partners = []
    within = max(ctx.objective.channel_cost(win.outputs).values()) <= 1.0
    for c in ([] if within else ranked):       # with the winner in, the model is within the data's uncertainty
        if (c.kind != "model" or c is win or c.J is None or c.coord is None or not c.sims
                or not float(c.J @ c.J) > 0 or c.reduction < LITTLE):
            continue
        j0 = near_off(ctx, c)
        share, size = promise(ctx, win, cols, j0)
        if share >= JOINT_PROMISE and size >= JOINT_SIZE * MIN_SIZE:
            partners.append((share, c, j0))
    partners = [(c, j0) for _, c, j0 in sorted(partners, key=lambda x: -x[0])[:JOINT_TOP]]
    if not earlier and not partners:
        return None
    start = (win.raw, win.outputs)
    tasks = ([("joint", fixed, base, start)] if earlier else [])
    for c, j0 in partners:
        m = Member.of(c)
        m.theta, m.J = 0.0, j0
        tasks.append(("joint", fixed, [*base, m], start))
    partners = [c for c, _ in partners]
    fits = map_tasks(ctx, tasks, workers, progress)
    rp.simulations += sum(f.sims for f in fits if isinstance(f, JointFit))
    refit = fits.pop(0) if earlier else None
    if isinstance(refit, Failed):
        refit = None
    w_at = len(earlier)
    pair, best_ic = None, math.inf
    info["tried"] = []
    for c, f in zip(partners, fits):
        if isinstance(f, Failed):
            info["tried"].append({"partner": c.effect.label(), "failed": f.message})
            continue
        p_beyond = joint_member(ctx, f, w_at + 1, refit.outputs if refit else win.outputs)
        w_beyond = joint_member(ctx, f, w_at, c.outputs)
        ok = p_beyond.eligible and w_beyond.eligible
        ic = ctx.objective.ic(f.outputs, len(f.members))
        info["tried"].append({"partner": p_beyond.effect.label(), "winner": w_beyond.effect.label(),
                              "partner_beyond": {"local_reduction": p_beyond.local_reduction,
                                                 "delta_ic": p_beyond.delta_ic, "eligible": p_beyond.eligible,
                                                 "note": p_beyond.note},
                              "winner_beyond": {"local_reduction": w_beyond.local_reduction,
                                                "delta_ic": w_beyond.delta_ic, "eligible": w_beyond.eligible,
                                                "note": w_beyond.note},
                              "correlation": float(f.corr[w_at, w_at + 1]), "simulations": f.sims})
        if ok and ic < best_ic:
            pair, best_ic = (f, w_beyond, p_beyond), ic
    chosen = []
    if pair is not None:
        chosen.append(pair)
    if refit is not None:
        chosen.append((refit, None, None))
    for f, w_beyond, p_beyond in chosen:
        ests = map_tasks(ctx, [("jrun", fixed, f, i) for i in range(bench.n)], workers, progress) if bench.n >= 2 else []
        rp.simulations += len(ests)
        runs = None if not ests or any(isinstance(e, Failed) for e in ests) else np.array(ests)
        cands = []
        for k, m in enumerate(f.members):
            if w_beyond is not None and k == w_at:
                cand = w_beyond
            elif p_beyond is not None and k == w_at + 1:
                cand = p_beyond
            else:
                cand = joint_member(ctx, f, k, ctx.outputs)
            if runs is not None:
                combine_runs(cand, list(runs[:, k]))
            cands.append(cand)
        new = cands[w_at:]
        unclear = [c for c in new if not abs(c.theta) >= CLEAR * c.u_theta]
        if p_beyond is not None and unclear:
            info["rejected"] = ("not added jointly: " + ", ".join(c.effect.label() for c in unclear) +
                                f" does not clear the off value by {CLEAR:g} of its 95 % joint interval")
            continue
        effects = [*fixed, *(c.effect for c in cands)]
        try:
            raw = rp.simulate(ctx.inputs, effects, fit=True)
        except RtsimError as exc:
            info["rejected"] = f"the joint values do not simulate ({str(exc).splitlines()[0][:80]})"
            continue
        rp.simulations += 1
        out = rp.reported(raw, ctx.inputs.t, effects)
        J = f.J
        for k, c in enumerate(cands):
            c.J = J[:, k].copy()
            c.raw, c.outputs = raw, out
        partner = cands[w_at + 1] if p_beyond is not None else None
        if partner is None and ctx.objective.cost(out) >= ctx.objective.cost(win.outputs):
            return None                     # the re-fit does not improve on the winner alone
        corr = f.corr
        parts = []
        if partner is not None:
            w, p = cands[w_at], partner
            parts.append(
                f"{w.effect.label()} and {p.effect.label()} fitted jointly remove "
                f"{100 * (1 - ctx.objective.cost(out) / ctx.cost):.0f} % of the disagreement; beyond the other, "
                f"{w.effect.name} removes {100 * w.local_reduction:.0f} % on its channels (IC {w.delta_ic:+.0f}) and "
                f"{p.effect.name} {100 * p.local_reduction:.0f} % (IC {p.delta_ic:+.0f}); correlation of their "
                f"sensitivities {corr[w_at, w_at + 1]:+.2f}")
        if earlier:
            parts.append("re-fitted jointly with the new effect: " + ", ".join(
                f"{a.effect.label()} -> {b.effect.label()}" for a, b in zip(earlier, cands[:w_at])))
        info["members"] = [c.effect.label() for c in cands]
        info["sensitivity_correlation"] = [[float(x) for x in row] for row in corr]
        return JointOutcome(cands, partner, list(earlier), out, raw, f, "; ".join(parts), info)
    return None
