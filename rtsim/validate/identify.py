"""Naming the missing effect: every candidate of the model's catalogue is fitted to the benchmark by
re-simulation, and the candidates are ranked by how much of the disagreement they remove, penalised
by their number of fitted values (objective.Objective.ic).

Fitting a model effect (one parameter p). The parameter is mapped to a coordinate theta that is 0 where
the effect is off (theta = p for additive parameters, p - 1 for a `scale`, the compliance 1/p for a
`stiffness`; the ParamSpec's `neutral`), so the nominal simulation is the theta = 0 point and costs
nothing. One trial simulation at a quarter of the plausible range gives a secant sensitivity J = d
residual / d theta and a Gauss-Newton step theta = -(J . r0) / (J . J), halved once when it costs more
than the model as it stands (the screening: two or three simulations). The responses are far from linear
in theta (a different brake friction moves the stop in time, and the residual of a moved event grows
faster than the shift; a softer tyre changes the slips and the yaw response roughly as 1/scale, so a
secant taken on the stiff side overshoots far on the soft side: the halving finds the valley), so
Gauss-Newton converges slowly from there: the best candidates (workflow.REFINE_TOP) continue with the
minimum of the cost bracketed (steps of 1.5 times the last distance) and found by Brent's method
(parabolic interpolation with golden-section safeguards, scipy) to a relative tolerance `TOL`, within
`MAX_SIMS` simulations. Values stay in the plausible range [lo, hi] of the catalogue's ParamSpec; when
the data ask for a value beyond it (the Gauss-Newton estimate or the slope at the bound points outside),
the candidate is rejected as implausible with the value asked for. A candidate that removes less than
`LITTLE` of the cost at the trial and the first step is not refined.

Sensor effects need no simulation of their own (Replayer.reported): bias and scale are linear least
squares on their channel, the delay is a grid search over its range refined by a parabola; their
sensitivity is seen through the nuisance adjustments, as the model effects' differences of residuals
are (Nuisance.project_direction). The workflow fits them on the per-run replays averaged (rebase).

Uncertainty (95 %) of a candidate (joint_uncertainty), from the residual r left at the optimum and the
sensitivity J (the secant to the nearest simulated point at least `SECANT` |theta| away), the model
error included, since data from elsewhere always leave a structural residual:
- the sandwich: r as the noise, samples correlated within a channel: var(theta) = sum_c tau_c
  mean(r_c^2) |J_c|^2 / (J . J)^2, tau_c the integrated autocorrelation time of the channel's residual;
- or, where larger, the delete-one-block jackknife over `SEGMENTS` time segments of every channel
  (_jackknife_sd): a structural residual that the fit leans on in some blocks and not in others pulls
  the blocks' values apart;
- then, in quadrature with 1.96 times that standard deviation, the discrepancy bound (_discrepancy):
  the change of theta that the residual left beyond the data's own uncertainty could cause, had it the
  shape of the sensitivity. A misfit that biases every block alike (a different tyre law) shows only
  here: the interval widens with the unexplained residual on the channels that carry the value.
What no residual shows is a structural mismatch with exactly the effect's signature on its channel: a lag
of the model's response reads as part of a sensor delay, a constant offset as part of a bias. The
interval then holds the value in the model's terms (the hidden value composed with what the model reads
in the same data without it), not the value alone.
The winner's value and interval then come from the runs one by one (run_estimate, combine_runs:
Student-t over the per-run estimates, as eq. 6).

Selection (channel_evidence, Candidate.eligible; issue 30). Residuals are the objective's: normalised by
each channel's standard error, the nuisance adjustments (objective.Nuisance) fitted at every candidate
value. A candidate is eligible when it is plausible and
- it predicts left-out runs better (crossval.leave_one_run_out: each run predicted from its own inputs
  by the model re-fitted on the other runs, a sensor effect applied to each run's own replay
  (sensor_deviations), the corrected resampled t-test over the folds at
  crossval.ALPHA; with fewer than 3 runs: the information criterion falls by MIN_DELTA_IC);
- it predicts no channel significantly worse (the same test per channel; for a sensor effect, its own
  channels: elsewhere only the nuisance adjustments' re-fit moves, which the test over all channels weighs)
  by a change that stands out of the mismatch the model had on that channel (made_worse: the fold test is
  blind to a structural mismatch in every run alike, which a true effect may move against a little);
- it moves its signature channels (a sensor effect: its own; a model effect: those whose left-out
  prediction it improves) by more than DISCREPANCY_Z (1.96) times the disagreement it leaves there
  (`left`, RMS in standard errors, at least 1: the structural mismatch and the noise left in the mean), the 95 %
  level of a discrepancy that may lie along the effect's signature: cross-validation across
  repetitions cannot see a structural mismatch, which is in every run alike;
- for a model effect, what the nuisance adjustments cannot reproduce of its change (free of their
  prior) still predicts left-out runs better;
- a sensor effect that a model-free relation of the vehicle's profile checks (redundancy: the gyro's lag
  against the yaw rate the rear wheel speeds give) is confirmed by it: a model whose yaw response lags
  reads as a gyro delay against the model, never against the wheels;
- it is not physically confounded: a gain or lag of accel_y asked for without the roll angle compared
  (TILT; body-frame accelerometers only), a gain or lag of the roll angle (ROLL_CONFOUNDED: the model's
  roll stiffness and damping), a grade asked for of level-frame data that never stand still
  (LEVEL_CONFOUNDED).
Eligible candidates are ranked by the share of the left-out runs' prediction loss they remove (the
largest first): among the effects the data support, the one that predicts unseen repetitions best. Every candidate
turned down carries one plain sentence saying why (Candidate.note; technical detail: Candidate.detail).

Several model effects at once (fit_joint, joint_member, joint_run_estimate). Fitted one by one, the first
of two model effects takes part of the second (a grade added first carries part of a hidden mass), and the
model then asks for wrong third effects. A joint fit is Gauss-Newton over the members' coordinates from
their single fits' sensitivities, updated by Broyden's rank-one rule after each simulation, refreshed by
finite differences when the steps stall (a secant from a single fit far away stalls it early), within
JOINT_SIMS simulations. Each member is then judged beyond the others with channel_evidence: the joint
outputs against the model without it, one value counted, so a member that only re-distributes what the
other explains is not eligible. Its interval is the joint one (joint_uncertainty with the Jacobian's
columns: the other members' uncertainty included), then combined with the runs' scatter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scipy.optimize import minimize_scalar
from scipy.stats import norm

from rtsim.errors import RtsimError
from rtsim.vehicle.kit.sensor_model import delayed

from .effectset import Effect
from .crossval import ALPHA, leave_one_run_out, normalised, p_better_than
from .objective import MOVING, Objective, _tau
from .redundancy import check
from .stats import parabolic_minimum, t_critical
from .replay import Replayer, ReplayInputs
from .signals import DERIVED

MAX_SIMS = 10                # simulations per candidate at most
TRIAL_FRACTION = 0.25
TOL = 0.003                  # relative tolerance on theta of the final 1-D minimisation
LITTLE = 0.02                # share of the cost a candidate must remove to be refined
SECANT = 0.05                # shortest relative secant for the sensitivity behind the uncertainty
#: an effect must move its channels by this many times the discrepancy it leaves (Candidate.outweighs_structure):
#: the two-sided 95 % quantile of the standard normal distribution
DISCREPANCY_Z = float(norm.ppf(0.975))


class _Budget(Exception):
    """The candidate's simulation budget is spent (or it is not worth more)."""
#: with fewer than 3 runs nothing can be cross-validated: the information criterion must then fall by this
#: much ("very strong" evidence on the Kass-Raftery scale of 2 ln(Bayes factor))
MIN_DELTA_IC = 10.0
MIN_SIZE = 1.0               # standard errors (RMS): the joint fit's partner search (joint.py) and the notes
CLEAR = 1.0                  # a winner's 95 % interval (runs one by one, model error included) excludes off
#: a lateral accelerometer on the body reads gravity's component g sin(roll), about proportional to the
#: lateral acceleration and lagging it with the roll dynamics: without the roll angle compared, a gain or a
#: lag of accel_y cannot be told from the model's roll (its roll stiffness, not in the catalogue)
TILT = {"accel_y": "roll"}
TILT_CONFOUNDED = ("sensor_scale", "sensor_delay")
#: a gain or a lag of the measured roll angle has the signature of the model's roll stiffness and roll
#: damping, which are not in the catalogue: an inclinometer's scale or delay cannot be told from them
ROLL_CONFOUNDED = {"roll": ("sensor_scale", "sensor_delay")}


def ratio_partner(profile, channel: str | None) -> str | None:
    """The channel whose scale the vehicle's profile declares identified only relative to ``channel``'s
    (``ratio_pairs``: a car's other wheel angle on the same axle, the axle's rolling radius a nuisance
    adjustment), else None: one relative scale per pair, so a second scale on a pair whose other channel
    carries one is not identifiable (channel_evidence)."""
    pairs = getattr(profile, "ratio_pairs", ())
    return next((b if a == channel else a for a, b in pairs if channel in (a, b)), None)


#: a level-frame accelerometer senses a grade as it senses a resistance (a constant longitudinal force while
#: the car moves: the resistance-offset nuisance), where a body-frame one senses no grade at all: in the level
#: frame a grade is told from a resistance only where the car stands still
LEVEL_CONFOUNDED = ("road_grade",)
NEUTRAL = {"scale": 1.0, "stiffness": math.inf}
SENSOR_FOR = {s: a for s, a in DERIVED.items()}      # wheel_speed_x -> wheel_angle_x


@dataclass
class Candidate:
    effect: Effect                      # the fitted effect (best value)
    kind: str
    k: int                              # fitted values counted by the information criterion
    cost: float
    ic: float
    reduction: float                    # share of the current cost it removes
    delta_ic: float                     # IC(candidate) - IC(current model)
    plausible: bool
    significant: bool
    match: float                        # cosine between the needed change and the effect's sensitivity
    match_by_channel: dict
    sims: int
    note: str = ""                      # one plain sentence: why it was turned down ("" while it is not)
    requested: float | None = None      # the (implausible) value the data asks for, when rejected
    outputs: dict = field(default_factory=dict, repr=False)     # model outputs with the effect
    raw: dict | None = field(default=None, repr=False)         # the same before sensor effects (model effects)
    points: list = field(default_factory=list, repr=False)     # (theta, raw outputs) simulated (model effects)
    theta: float = 0.0                                         # fitted coordinate (see Coord)
    u_theta: float = math.inf                                  # its 95 % half-width
    J: np.ndarray | None = field(default=None, repr=False)     # d residual / d theta there
    coord: object = field(default=None, repr=False)
    per_run: list = field(default_factory=list)                # theta_i -> values from the per-run replays
    size: float = 0.0                   # how far it moves the model's outputs, RMS in standard errors
    by_channel: dict = field(default_factory=dict)     # channel -> (cost before, cost with it, moved by)
    signature: list = field(default_factory=list)      # the channels it moves (its own one for a sensor)
    local_reduction: float = 0.0        # share of the cost on its signature channels it removes
    worse: list = field(default_factory=list)          # channels it makes significantly worse
    left: float = 0.0                   # RMS normalised residual left on its signature channels
    moved: float = 0.0                  # RMS normalised change on its signature channels
    joint: tuple | None = None          # (model effect, correlation) when judged jointly with a model effect
    confounded: str = ""                # why the data cannot tell it from the model's structure
    cv: object = field(default=None, repr=False)       # crossval.CrossValidation against the model as it stands
    detail: str = ""                    # how it was fitted and judged (technical, "; "-separated)
    structure: float = 0.0              # RMS structural mismatch (noise removed) left on its signature channels

    @property
    def outweighs_structure(self) -> bool:
        """It changes its signature channels by more than DISCREPANCY_Z times the disagreement it leaves
        there (`left`: the structural mismatch and the noise left in the data's mean). The disagreement
        is a model discrepancy of unknown shape: taken as a zero-mean random signal of RMS `left` that may
        lie wholly along the effect's signature (the least favourable case: a structural gain reads as a
        sensor gain), its share along the signature is below DISCREPANCY_Z `left` with 95 % probability,
        so an effect that moves the channels further stands out of it at that level. An effect inside it
        cannot be told apart from the structure, however consistently every run shows it. The mismatch is
        never taken below 1 standard error, the noise left in the data's mean: a residual smaller than that
        says the discrepancy cannot be resolved, not that it is absent."""
        return self.moved >= DISCREPANCY_Z * max(self.left, 1.0)

    @property
    def predicts(self) -> bool:
        """It predicts left-out runs better (crossval; with fewer than 3 runs: the information criterion
        falls by MIN_DELTA_IC)."""
        if self.cv is not None:
            return self.cv.better
        return self.delta_ic <= -MIN_DELTA_IC

    @property
    def score(self) -> float:
        """What ranks the candidates (lower first): the share of the left-out runs' prediction loss it
        removes, negated (the expected prediction error is the selection criterion; the fold test only
        says whether the improvement is real), else its IC."""
        if self.cv is not None:
            return -self.cv.gain
        return self.delta_ic

    @property
    def eligible(self) -> bool:
        return (self.plausible and self.predicts and not self.worse and self.outweighs_structure
                and not self.confounded)

    def summary(self) -> dict:
        return {"name": self.effect.name, "parameters": dict(self.effect.params),
                "uncertainty": dict(self.effect.uncertainty), "cost": self.cost, "ic": self.ic,
                "delta_ic": self.delta_ic, "reduction": self.reduction, "plausible": self.plausible,
                "significant": self.significant, "signature_match": self.match, "simulations": self.sims,
                "signature_channels": self.signature, "local_reduction": self.local_reduction,
                "worse_channels": self.worse, "moved": self.moved, "left": self.left,
                "structure": self.structure, "eligible": self.eligible,
                "cross_validation": self.cv.summary() if self.cv is not None else None,
                "by_channel": {c: {"cost_before": v[0], "cost_with": v[1], "moved": v[2]}
                               for c, v in self.by_channel.items()},
                "note": self.note, "detail": self.detail, **({"requested": self.requested} if self.requested is not None else {})}


@dataclass
class Context:
    """What every candidate fit of one iteration shares."""
    bench: object
    objective: Objective
    replayer: Replayer
    inputs: ReplayInputs
    effects: list[Effect]               # the model as it stands (accepted effects)
    outputs: dict                       # its outputs (sensor effects applied)
    raw: dict                           # its outputs before sensor effects
    cost: float
    n_runs: int
    deviations: list | None = None      # per run: its replay's normalised outputs minus their mean (crossval)
    run_raws: list | None = None        # per run: its replay's physical outputs (the ensemble's; sensor_deviations)

    @property
    def catalogue(self) -> dict:
        """The vehicle's effect catalogue (its validation profile's, carried by the replayer): name ->
        EffectSpec."""
        return self.replayer.profile.effects


# ------------------------------------------------------------------------------ parameter mapping
class Coord:
    """theta <-> parameter value for one parameter (see the module docstring). The off value is the
    ParamSpec's `neutral` (None: none, e.g. an infinitely stiff driveline, fitted as 1/p)."""

    def __init__(self, pspec, lo: float | None = None, hi: float | None = None):
        self.name = pspec.name
        self.lo = float(pspec.lo if lo is None else lo)
        self.hi = float(pspec.hi if hi is None else hi)
        neutral = getattr(pspec, "neutral", NEUTRAL.get(pspec.name, 0.0))
        self.neutral = math.inf if neutral is None else float(neutral)
        self.inverse = math.isinf(self.neutral)
        a, b = self.theta(self.lo), self.theta(self.hi)
        self.tlo, self.thi = min(a, b), max(a, b)

    def theta(self, p: float) -> float:
        if self.inverse:
            return 1.0 / p if p > 0 else math.inf
        return p - self.neutral

    def value(self, th: float) -> float:
        if self.inverse:
            return 1.0 / th if th > 0 else math.inf
        return th + self.neutral

    def value_uncertainty(self, th: float, uth: float) -> float:
        if self.inverse:
            return uth / (th * th) if th > 0 else math.inf
        return uth

    def trial(self) -> float:
        hi = self.thi if self.thi > 0 else self.tlo
        return TRIAL_FRACTION * hi

    def clip(self, th: float) -> float:
        return min(max(th, self.tlo), self.thi)


def _numeric_params(spec) -> list:
    return [p for p in spec.params if p.name != "channel"]


def _uncertainty(ctx: Context, J: np.ndarray, out: dict) -> float:
    """95 % half-width of theta from the residual left at the optimum (module docstring)."""
    if not float(J @ J) > 0.0:
        return math.inf
    return float(joint_uncertainty(ctx.objective, J[:, None], ctx.objective.residual(out))[0][0])


def _match(ctx: Context, J: np.ndarray, sign: float) -> tuple[float, dict]:
    """Cosine similarity of the effect's sensitivity (signed towards the fit) with the needed change."""
    need = -ctx.objective.residual(ctx.outputs)
    d = sign * J
    out = float(d @ need / (np.linalg.norm(d) * np.linalg.norm(need) + 1e-300))
    by = {}
    n = ctx.objective.mean[ctx.objective.channels[0]].size
    for i, c in enumerate(ctx.objective.channels):
        a, b = d[i * n:(i + 1) * n], need[i * n:(i + 1) * n]
        na, nb = np.linalg.norm(a), np.linalg.norm(b)
        by[c] = float(a @ b / (na * nb)) if na > 0 and nb > 0 else 0.0
    return out, by


def _finish(ctx: Context, effect: Effect, kind: str, k: int, out: dict, J: np.ndarray, th: float,
            coord: Coord, sims: int, requested: float | None, note: str) -> Candidate:
    obj = ctx.objective
    cost = obj.cost(out)
    uth = _uncertainty(ctx, J, out)
    u = coord.value_uncertainty(th, uth)
    effect.set_interval(coord.name, u, u)
    significant = bool(abs(th) > uth) and np.isfinite(uth)
    match, by = _match(ctx, J, 1.0 if th >= 0 else -1.0)
    plausible = requested is None
    notes = [note] if note else []
    if plausible and not significant:
        notes.append(f"{coord.name} = {coord.value(th):.4g} +- {effect.uncertainty[coord.name]:.2g}: the interval "
                     f"includes the off value")
    ic = obj.ic(out, k)
    # how far it moves the outputs: a sensor effect on its own channel(s), where it is judged (a move
    # spread over every compared channel would shrink with their number)
    size = distance(obj, out, ctx.outputs, _own(obj, effect.channel) if kind == "sensor" else None)
    cand = Candidate(effect, kind, k, cost, ic, 1.0 - cost / ctx.cost, ic - obj.ic(ctx.outputs, 0), plausible,
                     significant, match, by, sims, "", requested, out, theta=th, u_theta=uth, J=J,
                     coord=coord, size=size, detail="; ".join(notes))
    if not plausible:
        cand.note = (f"The data ask for {coord.name} = {requested:.4g}, outside its plausible range {coord.lo:g} to "
                     f"{coord.hi:g}.")
    channel_evidence(ctx, cand)
    return cand


def _moves_throughout(ctx: Context) -> bool:
    """Whether the benchmark's mean wheel speeds say the car moves (faster than objective.MOVING) at every
    sample."""
    obj = ctx.objective
    w = [obj.mean[c] for c in obj.channels if c.startswith("wheel_speed_")]
    return bool(w) and bool(np.all(np.abs(np.mean(w, axis=0)) * ctx.replayer.wheel_radius > MOVING))


def _own(obj: Objective, sensor: str) -> list[str]:
    """The compared channels a sensor effect on `sensor` changes: its own, or the wheel speed derived from a
    wheel angle."""
    return [c for c in obj.channels if c == sensor or SENSOR_FOR.get(c) == sensor]


def sensor_deviations(ctx: Context, effect: Effect) -> list | None:
    """Per run: its own replay (ctx.run_raws) as the sensors report it with the sensor effect `effect` on top
    of the model's effects, normalised, minus the mean over the runs; None without the runs' replays. The
    cross-validation predicts each run from these when it judges a sensor effect (crossval, `cand_deviations`):
    the effect acts on each run's own readings, so a delay moves each run's own transitions (a run that
    brakes 30 ms early keeps its early stop, delayed), where the model's deviations with the effect's change
    on the mean added would put the delayed stop at the mean's time in every run. No simulation: a sensor
    effect changes the readings, not the motion."""
    if ctx.run_raws is None or ctx.deviations is None or len(ctx.run_raws) != len(ctx.deviations):
        return None
    obj, rp = ctx.objective, ctx.replayer
    effects = [*ctx.effects, effect]
    per_run = [normalised(obj, rp.reported(r, ctx.bench.t, effects)) for r in ctx.run_raws]
    mean = np.mean(per_run, axis=0)
    return [x - mean for x in per_run]


def channel_evidence(ctx: Context, cand: Candidate) -> None:
    """What decides a candidate (module docstring, "Selection"): its leave-one-run-out cross-validation
    against the model as it stands (crossval), its signature channels (a sensor effect: its own channel;
    a model effect: the channels whose left-out-run prediction it improves, else the one it moves most),
    how far it moves them and the structural mismatch it leaves there, and whether the nuisance
    adjustments could stand in for it. Per channel also the cost before and with it and how far it moves
    it (`by_channel`), the share of the signature channels' cost it removes and their information
    criterion, for the report."""
    obj = ctx.objective
    if not cand.outputs:
        return
    ra, rb = obj.channel_residual(cand.outputs), obj.channel_residual(ctx.outputs)
    by = {}
    for c in obj.channels:
        d = ra[c] - rb[c]
        by[c] = (float(np.mean(rb[c] ** 2)), float(np.mean(ra[c] ** 2)), float(np.sqrt(np.mean(d * d))))
    cand.by_channel = by
    m0, m1 = normalised(obj, ctx.outputs), normalised(obj, cand.outputs)
    J = cand.J if cand.J is not None and float(cand.J @ cand.J) > 0 else None
    own = sensor_deviations(ctx, cand.effect) if cand.kind == "sensor" else None
    co = cand.coord
    span = (-math.inf, math.inf) if co is None else (co.tlo - cand.theta, co.thi - cand.theta)
    cand.cv = leave_one_run_out(obj, m0, m1, J, ctx.deviations, own, span)
    if cand.kind == "sensor":
        sig = _own(obj, cand.effect.channel)
    elif cand.cv is not None:
        sig = [c for c in obj.channels if cand.cv.improves(c)] or [max(by, key=lambda c: by[c][2])]
    else:
        sig = [max(by, key=lambda c: by[c][2])]
    cand.signature = sig
    before = sum(by[c][0] for c in sig)
    after = sum(by[c][1] for c in sig)
    cand.local_reduction = 1.0 - after / before if before > 0 else 0.0
    cand.left = math.sqrt(after / len(sig))
    # the normalised residual of a model within the data's own uncertainty has a mean square of 1: what
    # is left beyond it is structural
    cand.structure = math.sqrt(max(after / len(sig) - 1.0, 0.0))
    cand.moved = math.sqrt(sum(by[c][2] ** 2 for c in sig) / len(sig))
    # a sensor effect changes its own channels only: what moves elsewhere is the nuisance adjustments'
    # re-fit (an axle's rolling radius shared by its two wheels), which the test over all channels weighs
    judged = sig if cand.kind == "sensor" else obj.channels
    cand.worse = made_worse(cand.cv, by, judged)
    inside = [c for c in judged if cand.cv is not None and cand.cv.worsens(c) and c not in cand.worse]
    if inside:
        add_detail(cand, "predicts " + ", ".join(inside) + " worse in left-out runs by a change inside the mismatch "
                         "the model had there (" + ", ".join(f"{by[c][2]:.2g} < {DISCREPANCY_Z:.2f} x "
                                                             f"{max(math.sqrt(by[c][0]), 1.0):.2g}" for c in inside)
                         + "): not counted as a trade")
    ntot = sum(obj.n_eff.values())
    local = sum(obj.n_eff[c] * (lr if c in sig else min(lr, 0.0)) for c in obj.channels
                for lr in [math.log(max(by[c][1], 1e-300) / max(by[c][0], 1e-300))])
    cand.delta_ic = local + cand.k * math.log(ntot)
    cand.ic = obj.ic(ctx.outputs, 0) + cand.delta_ic
    ch = cand.effect.channel
    if (cand.kind == "sensor" and cand.effect.name in TILT_CONFOUNDED and ch in TILT and TILT[ch] not in obj.channels
            and ctx.replayer.accel_frame == "body"):          # a level-frame accelerometer senses no tilt
        what = cand.effect.name.split("_")[1]
        cand.confounded = (f"a {what} of {ch} cannot be told from the model's body {TILT[ch]} (the accelerometer "
                           f"reads g sin({TILT[ch]})): record {TILT[ch]} to tell them apart")
    if cand.kind == "sensor" and cand.effect.name in ROLL_CONFOUNDED.get(ch, ()):
        what = cand.effect.name.split("_")[1]
        cand.confounded = (f"a {what} of the {ch} angle cannot be told from the model's roll stiffness and damping, "
                           "which the catalogue does not hold")
    partner = ratio_partner(ctx.replayer.profile, ch) if cand.effect.name == "sensor_scale" else None
    if partner and not cand.confounded and any(e.name == "sensor_scale" and e.channel == partner
                                               for e in ctx.effects):
        cand.confounded = (f"{partner} already carries a scale: with the axle's rolling radius adjusted, the "
                           f"two wheels' scales are known only relative to each other, and that ratio is named")
    if cand.kind == "sensor" and not cand.confounded:
        cand.confounded = model_free_check(ctx, cand)
    if cand.kind == "sensor" and not cand.confounded:
        cand.confounded = kinematic_gain_check(ctx, cand)
    if (cand.effect.name in LEVEL_CONFOUNDED and ctx.replayer.accel_frame == "level" and obj.nuisance is not None
            and _moves_throughout(ctx)):
        cand.confounded = ("in the level frame a grade reads as a constant resistance (the resistance-offset "
                           "adjustment) while the car moves, and it never stands still here: record the body "
                           "frame (its accel_x senses no grade) to tell them apart")
    if cand.kind == "model" and obj.nuisance is not None and not cand.confounded and cand.cv is not None \
            and cand.cv.better:
        # the part of its change the nuisance adjustments cannot reproduce (free of their prior, inside
        # their ranges) must predict left-out runs better on its own: else the adjustments stand for it
        nu = obj.nuisance
        p = np.clip(np.linalg.lstsq(nu.D, m1 - m0, rcond=None)[0], nu.lo, nu.hi)
        beyond = leave_one_run_out(obj, m0, m1 - nu.D @ p, None, ctx.deviations)
        if beyond is not None and not beyond.better:
            share, _ = nu.mimic(m1 - m0)
            who = " and the named sensor effects re-fitted" if nu.refits else ""
            cand.confounded = (f"the nuisance adjustments (rolling radii, resistance offset){who} reproduce "
                               f"{100 * share:.0f} % of what it changes, and the rest does not improve the "
                               f"prediction of left-out runs")
    explain_rejection(cand)


def made_worse(cv, by: dict, channels: list[str]) -> list[str]:
    """The channels a candidate trades away: its left-out-run prediction there is significantly worse
    (crossval: the paired fold test at ALPHA) and its change there stands out of the mismatch the model
    had on that channel, moving it (RMS, standard errors) by at least DISCREPANCY_Z times the channel's
    RMS residual before it (at least 1, the noise left in the mean). `by`: channel -> (cost before, cost
    with it, moved by), as channel_evidence keeps them. The fold test sees the runs' scatter, not what
    every run shares: a channel with a structural mismatch (a different tyre law, a missing roll) that
    the effect moves a little against it is predicted worse in every left-out run alike, however small
    the move. As in Candidate.outweighs_structure, a change inside DISCREPANCY_Z times that mismatch
    cannot be told from a discrepancy of unknown shape lying along it, at the 95 % level; a change that
    stands out of it makes a mismatch of its own (the effect trades one mismatch for another)."""
    if cv is None:
        return []
    return [c for c in channels if cv.worsens(c) and by[c][2] >= DISCREPANCY_Z * max(math.sqrt(by[c][0]), 1.0)]


def model_free_check(ctx: Context, cand: Candidate) -> str:
    """Why a sensor effect is the model's structure and not the sensor, from a model-free relation of the
    vehicle's profile that checks it (redundancy): the relation's sentence when the data's channels do
    not confirm the candidate's value, "" when they do or no relation checks it."""
    rel = next((r for r in getattr(ctx.replayer.profile, "relations", ())
                if r.channel == cand.effect.channel and cand.effect.name in r.checks), None)
    if rel is None or cand.coord is None:
        return ""
    obj = ctx.objective
    n = max(obj.runs[c].shape[0] for c in obj.channels)
    runs = [{c: obj.runs[c][i] for c in obj.channels if i < obj.runs[c].shape[0]} for i in range(n)]
    t = ctx.inputs.t
    kind = "scale" if cand.effect.name == "sensor_scale" else "delay"
    ck = check(rel, kind, runs, ctx.outputs, float(t[1] - t[0]))
    if ck is None:
        return ""
    value = cand.coord.value(cand.theta)
    add_detail(cand, f"model-free check against {rel.says}: {ck.value:.4g} +- {ck.half_width:.2g}")
    return "" if ck.confirms(value) else ck.sentence(value)


def kinematic_gain_check(ctx: Context, cand: Candidate) -> str:
    """Why a scale of a channel the vehicle's profile ties kinematically to another (`gain_pairs`; the
    car's gyro_z and accel_y, a_y = v r in steady cornering) is the vehicle's own response and not the
    sensor: a car whose yaw response is larger than the model's (its cornering stiffness, yaw inertia or
    load transfer; not in the catalogue) shows the same gain on both, a sensor's scale on its own channel
    only. The alternative that both channels of the pair carry one common gain k (the model's outputs
    on both times k, k fitted like the candidate: least squares through the nuisance adjustments, re-fitted
    in each fold; on top of the effects already named, a scale of the other channel included) is
    cross-validated over the same folds against the same model, and the candidate must
    predict the left-out runs better than it (crossval.p_better_than, one-sided at ALPHA). Both have one
    value; where the runs cannot prefer the sensor's own channel, the gain is the car's as likely as the
    sensor's, and it is not named. "" when it is, or when the check does not apply."""
    obj = ctx.objective
    ch = cand.effect.channel
    pairs = getattr(ctx.replayer.profile, "gain_pairs", ())
    other = next((b if a == ch else a for a, b in pairs if ch in (a, b)), None) \
        if cand.effect.name == "sensor_scale" else None
    if other is None or other not in obj.channels or cand.cv is None:
        return ""
    n = obj.mean[obj.channels[0]].size
    d = np.zeros(n * len(obj.channels))
    pair = np.zeros_like(d)                 # 1 on the pair's samples
    for c in (ch, other):
        i = obj.channels.index(c)
        d[i * n:(i + 1) * n] = ctx.outputs[c] / obj.scale[c]
        pair[i * n:(i + 1) * n] = 1.0
    J = obj.nuisance.project_direction(d) if obj.nuisance is not None else d
    jj = float(J @ J)
    if not jj > 0.0:
        return ""
    k = -float(J @ obj.residual(ctx.outputs)) / jj
    m0 = normalised(obj, ctx.outputs)
    # each run's readings carry the common gain too, like the candidate's own (sensor_deviations)
    gained = None if ctx.deviations is None else [x + k * pair * x for x in ctx.deviations]
    alt = leave_one_run_out(obj, m0, m0 + k * d, J, ctx.deviations, gained)
    if alt is None:
        return ""
    p = p_better_than(cand.cv, alt)
    add_detail(cand, f"common gain of {ch} and {other}: {1 + k:.4g}, removes {100 * alt.gain:.0f} % of the "
                     f"left-out loss; the scale predicts better with p = {p:.2g}")
    if p < ALPHA:
        return ""
    return (f"a common gain of {ch} and {other} ({1 + k:.4g}: the car's own yaw response differing from the "
            f"model's, which the catalogue does not hold) predicts the left-out runs as well, so the runs cannot "
            f"say the gain is the sensor's")


def add_detail(cand: Candidate, text: str) -> None:
    """Append to the candidate's technical detail."""
    cand.detail = (cand.detail + "; " if cand.detail else "") + text


def explain_rejection(cand: Candidate) -> None:
    """The one sentence (Candidate.note) that says why a candidate is turned down, in the order the
    rules apply; "" when it is eligible (the workflow may still turn it down: workflow._turned_down)."""
    if not cand.plausible:
        return                               # _finish said what value the data ask for
    sig = ", ".join(cand.signature)
    if cand.confounded:
        cand.note = cand.confounded[0].upper() + cand.confounded[1:] + "."
    elif not cand.predicts:
        cand.note = ("It did not improve the prediction of left-out runs" + (
            f" (held-out error {100 * -cand.cv.gain:+.0f} %, p = {cand.cv.p_better:.2g})." if cand.cv is not None
            else " (fewer than 3 runs: the information criterion did not fall enough)."))
    elif cand.worse:
        cand.note = (f"It predicts {', '.join(cand.worse)} worse in left-out runs while it improves "
                     f"{sig}: it trades one mismatch for another.")
    elif not cand.outweighs_structure:
        cand.note = (f"It changes {sig} by {cand.moved:.2g} standard errors, less than {DISCREPANCY_Z:.2f} times "
                     f"the mismatch it leaves there ({max(cand.left, 1.0):.2g}, at least the noise left in the "
                     f"mean), so it cannot be told apart from the model's structural mismatch.")
    else:
        cand.note = ""


# --------------------------------------------------------------------------------- model effects
def fit_model_effect(ctx: Context, name: str, budget: int = MAX_SIMS,
                     seed: list[tuple[float, dict]] | None = None) -> Candidate:
    """Fit the model effect `name` by re-simulation (module docstring) with at most `budget`
    simulations in all, continuing from the simulations `seed` ((theta, raw outputs) of a screening)."""
    spec = ctx.catalogue[name]
    params = _numeric_params(spec)
    coord = Coord(params[0])
    obj = ctx.objective
    others = {p.name: float(p.default) for p in params[1:]}

    def simulate(th: float):
        e = Effect(name, {coord.name: coord.value(th), **others})
        raw = ctx.replayer.simulate(ctx.inputs, [*ctx.effects, e], fit=True)
        raws[th] = raw
        return ctx.replayer.reported(raw, ctx.inputs.t, ctx.effects)

    raws: dict[float, dict] = {}
    r0 = obj.residual(ctx.outputs)
    pts: list[tuple[float, np.ndarray, dict]] = [(0.0, r0, ctx.outputs)]
    for th, raw in seed or []:
        raws[th] = raw
        out = ctx.replayer.reported(raw, ctx.inputs.t, ctx.effects)
        pts.append((th, obj.residual(out), out))
    note = ""
    requested = None
    span = coord.thi - coord.tlo
    c0 = float(r0 @ r0)

    def sq(p):
        return float(p[1] @ p[1])

    def f(th: float) -> float:
        """Cost at theta (sum of squares), simulating once per distinct value."""
        nonlocal note
        th = coord.clip(float(th))
        for p in pts:
            if p[0] == th:
                return sq(p)
        if len(pts) >= budget + 1:
            raise _Budget
        try:
            out = simulate(th)
        except RtsimError as exc:          # the model cannot run there: infinitely bad
            note = f"simulation failed at {coord.name} = {coord.value(th):.4g} ({str(exc).splitlines()[0][:80]})"
            pts.append((th, np.full_like(r0, 1e150), {}))
            return math.inf
        pts.append((th, obj.residual(out), out))
        return sq(pts[-1])

    try:
        # trial point, then one Gauss-Newton step with the secant through the nominal point
        t1 = coord.clip(coord.trial())
        f(t1)
        J = (next(p for p in pts if p[0] == t1)[1] - r0) / (t1 - 0.0)
        jj = float(J @ J)
        free = -float(J @ r0) / jj if jj > 0 else 0.0
        t2 = coord.clip(free)
        if abs(free - t2) > 0.05 * span:
            requested = free
        if t2 not in (0.0, t1) and f(t2) > c0 and t2 / 2.0 not in (0.0, t1):
            f(t2 / 2.0)                    # damped Gauss-Newton: a step that overshoots is halved
        best = min(pts, key=sq)
        if sq(best) > (1.0 - LITTLE) * c0:
            raise _Budget                  # neither the trial nor the step helps: not worth more
        # bracket the minimum: a point on each side of the best with a higher cost
        for _ in range(4):
            best = min(pts, key=sq)
            lower = [p for p in pts if p[0] < best[0]]
            upper = [p for p in pts if p[0] > best[0]]
            if lower and upper:
                break
            near = min(lower or upper, key=lambda p: abs(p[0] - best[0]))
            ext = coord.clip(best[0] + 1.5 * (best[0] - near[0]))
            if ext == best[0]:             # the best value is on the bound of the plausible range
                break
            f(ext)
        best = min(pts, key=sq)
        lower = [p for p in pts if p[0] < best[0]]
        upper = [p for p in pts if p[0] > best[0]]
        if lower and upper:
            requested = None
            a = max(lower, key=lambda p: p[0])[0]
            c = min(upper, key=lambda p: p[0])[0]
            try:
                minimize_scalar(f, bracket=(a, best[0], c), method="brent",
                                options={"xtol": TOL, "maxiter": MAX_SIMS})
            except ValueError:         # a flat stretch (equal costs): no strict bracket
                minimize_scalar(f, bounds=(a, c), method="bounded",
                                options={"xatol": TOL * max(abs(best[0]), 0.02 * span), "maxiter": MAX_SIMS})
        elif requested is None:
            # on a bound: the local slope says where the data would like to go
            near = min((p for p in pts if p is not best), key=lambda p: abs(p[0] - best[0]))
            J = (best[1] - near[1]) / (best[0] - near[0])
            free = best[0] - float(J @ best[1]) / float(J @ J)
            if abs(free - coord.clip(free)) > 0.05 * span:
                requested = free
    except _Budget:
        pass
    if requested is not None:
        requested = coord.value(requested) if (not coord.inverse or requested > 0) else 0.0
    pts = [p for p in pts if p[2]]
    sims = len(pts) - 1
    if len(pts) < 2:
        eff = Effect(name, {coord.name: coord.value(coord.clip(coord.trial())), **others})
        cand = _finish(ctx, eff, "model", 1, ctx.outputs, np.zeros_like(r0), 0.0, coord, sims, None, note)
        cand.plausible = False
        return cand
    best = min(pts, key=lambda p: float(p[1] @ p[1]))
    if best[0] == 0.0:             # no value tried improves on the model as it stands
        best = min(pts[1:], key=lambda p: float(p[1] @ p[1]))
        note = (note + "; " if note else "") + "no value tried improves the fit"
    # sensitivity for the uncertainty: the secant to the nearest point at least SECANT |theta| away (a
    # closer one may sit on a step of a non-smooth response, e.g. the moment a held wheel breaks away)
    others_ = [p for p in pts if p is not best]
    far = [p for p in others_ if abs(p[0] - best[0]) >= SECANT * max(abs(best[0]), 0.02 * span)]
    partner = min(far or others_, key=lambda p: abs(p[0] - best[0]))
    J = (best[1] - partner[1]) / (best[0] - partner[0])
    eff = Effect(name, {coord.name: coord.value(best[0]), **others})
    cand = _finish(ctx, eff, "model", 1, best[2], J, best[0], coord, sims, requested, note)
    cand.raw = raws.get(best[0])
    cand.points = [(p[0], raws[p[0]]) for p in pts if p[0] in raws]
    return cand


# -------------------------------------------------------------------------------- sensor effects
def _sensor_channels(ctx: Context) -> list[tuple[str, str]]:
    """(compared channel, sensor channel it comes from)."""
    return [(c, SENSOR_FOR.get(c, c)) for c in ctx.objective.channels]


def fit_sensor_effects(ctx: Context) -> list[Candidate]:
    """Every sensor effect on every compared channel (no simulation: the sensor model on the current outputs)."""
    cat = ctx.catalogue
    obj = ctx.objective
    t = ctx.inputs.t
    n = t.size
    cands = []
    taken = {e.key for e in ctx.effects}
    for name, spec in cat.items():
        if spec.kind != "sensor":
            continue
        params = _numeric_params(spec)
        if len(params) != 1:
            continue
        for ci, (comp, sensor) in enumerate(_sensor_channels(ctx)):
            if (name, sensor) in taken:
                continue
            if name == "sensor_bias" and sensor != comp:
                continue            # a wheel-angle bias does not show in the wheel speed
            bounds = spec.bounds(params[0].name, sensor) if hasattr(spec, "bounds") else (None, None)
            coord = Coord(params[0], *bounds)
            base = ctx.outputs
            y = base[comp]
            s = obj.scale[comp]
            r0 = obj.residual(base)
            seg = slice(ci * n, (ci + 1) * n)

            def with_value(v: float) -> dict:
                e = Effect(name, {"channel": sensor, coord.name: v})
                return ctx.replayer.reported(ctx.raw, t, [*ctx.effects, e])

            def direction(change: np.ndarray, seg=seg, s=s) -> np.ndarray:
                """d residual / d value: `change` on the channel, as the residual sees it (the model
                effects' J are differences of residuals): the nuisance adjustments absorb their share."""
                J = np.zeros_like(r0)
                J[seg] = change / s
                return obj.nuisance.project_direction(J) if obj.nuisance is not None else J

            if name == "sensor_bias":
                J = direction(np.ones(n))
            elif name == "sensor_scale":
                J = direction(y)
            if name in ("sensor_bias", "sensor_scale"):
                jj = float(J @ J)
                free = -float(J @ r0) / jj if jj > 0 else 0.0
            else:   # delay: grid then parabola
                grid = np.linspace(coord.tlo, coord.thi, 81)
                costs = []
                for d in grid:
                    yd = delayed(y, float(t[1] - t[0]), d)
                    costs.append(float(np.sum(((yd - obj.mean[comp]) / s) ** 2)))
                free = parabolic_minimum(grid, costs)
                J = direction(-np.gradient(delayed(y, float(t[1] - t[0]), free), t))
            th = coord.clip(free)
            span = coord.thi - coord.tlo
            requested = coord.value(free) if abs(free - th) > 0.05 * span else None
            out = with_value(coord.value(th))
            eff = Effect(name, {"channel": sensor, coord.name: coord.value(th)})
            cands.append(_finish(ctx, eff, "sensor", 2, out, J, th, coord, 0, requested,
                                 "fitted on the model outputs (no re-simulation)"))
    return cands


REFIT_STEP = 0.01            # finite-difference step of a named sensor effect's re-fit, share of its range


def sensor_refits(ctx: Context, raw: dict, effects: list[Effect],
                  named: list[Effect]) -> tuple[list[str], list, list, list]:
    """The named sensor effects (`named`, which are in `effects`, the model as it stands) as adjustments
    re-fitted beside every later candidate (Objective.refitting): their labels, the change of the
    normalised residual per unit of each value on the physical outputs `raw` (a bias and a scale act
    linearly; a delay's change is linearised), and the change of value (lo, hi) its plausible range
    allows. A sensor effect named before a model effect was fitted without it: where the model effect
    also moves that channel, the sensor's value has taken part of it, and held fixed it would fight the
    model effect's change there."""
    obj = ctx.objective
    t = ctx.inputs.t
    rp = ctx.replayer
    base = normalised(obj, rp.reported(raw, t, effects))
    names, cols, lo, hi = [], [], [], []
    for e in named:
        if e.kind != "sensor":
            continue
        spec = ctx.catalogue[e.name]
        pspec = _numeric_params(spec)[0]
        bounds = spec.bounds(pspec.name, e.channel) if hasattr(spec, "bounds") else (None, None)
        coord = Coord(pspec, *bounds)
        v = float(e.params[pspec.name])
        h = REFIT_STEP * (coord.hi - coord.lo)
        if v + h > coord.hi:
            h = -h
        moved = Effect(e.name, {**e.params, pspec.name: v + h})
        out = rp.reported(raw, t, [moved if x is e else x for x in effects])
        names.append(e.label())
        cols.append((normalised(obj, out) - base) / h)
        lo.append(coord.lo - v)
        hi.append(coord.hi - v)
    return names, cols, lo, hi


def refit_named_sensors(ctx: Context, raw: dict, effects: list[Effect],
                        named: list[Effect]) -> list[tuple[str, str]]:
    """Re-fit the named sensor effects (`named`, in `effects`) in place on the model as it now stands (its
    physical outputs `raw`), jointly with the nuisance adjustments (sensor_refits; a delay's linearised
    step taken twice); their intervals keep their width. (label before, label after) of those whose
    value moved."""
    sensors = [e for e in named if e.kind == "sensor"]
    before = [e.label() for e in sensors]
    for _ in range(2):
        names, cols, lo, hi = sensor_refits(ctx, raw, effects, sensors)
        if not cols:
            return []
        obj = ctx.objective.refitting(names, cols, lo, hi)
        out = ctx.replayer.reported(raw, ctx.inputs.t, effects)
        for e, d in zip(sensors, obj.nuisance.refit_values(obj.raw_residual(out))):
            pname = _numeric_params(ctx.catalogue[e.name])[0].name
            e.params[pname] = float(e.params[pname]) + float(d)
        if not any(e.name == "sensor_delay" for e in sensors):
            break
    return [(b, e.label()) for b, e in zip(before, sensors) if e.label() != b]


def rebase(cands: list[Candidate], ctx: Context) -> None:
    """Sensor candidates fitted and judged in another context of the same model (the per-run replays
    averaged, workflow) re-expressed against `ctx` (the mean-input replay the iteration ranks on): their
    IC is ctx's plus the difference they make there, their outputs ctx's with them applied. Their
    value, evidence, reduction and interval stay the ones of the context they were fitted in (there
    the mean-input replay's averaging artefact is gone, which is no model error of theirs)."""
    ic0 = ctx.objective.ic(ctx.outputs, 0)
    for c in cands:
        c.ic = ic0 + c.delta_ic
        c.outputs = ctx.replayer.reported(ctx.raw, ctx.inputs.t, [*ctx.effects, c.effect])


# ------------------------------------------------------------------------------ per-run estimates
def run_estimate(ctx: Context, cand: Candidate, i: int, raw: dict | None = None) -> float:
    """Run i's own estimate of the winner's coordinate: the model with the winner at theta* replayed
    with run i's own inputs, and one Gauss-Newton step from theta* against run i's channels,
    theta_i = theta* - (J . r_i) / (J . J). Replaying each run's own inputs removes the bias that
    averaging runs with slightly different event times gives to the mean (an onset of motion or a
    stop smeared by the averaging, against the model's crisp one); these replays run at the model's
    own step (dt), which also removes the small bias of fitting at fit_dt. The interval combine_runs
    draws from them covers the run-to-run scatter, not systematic errors of the rest of the model.
    `raw`: run i's replay of the model without the candidate, given for a sensor effect (which does not
    change the car's motion, only what the sensors report of it): no simulation then."""
    effects = [*ctx.effects, cand.effect]
    inp = ctx.replayer.inputs(ctx.bench, run=i)
    if raw is None:
        raw = ctx.replayer.simulate(inp, effects)    # at the model's own step: no discretisation bias
    out = ctx.replayer.reported(raw, inp.t, effects)
    r = ctx.objective.residual_to_run(out, i)
    return cand.theta - float(cand.J @ r) / float(cand.J @ cand.J)


def combine_runs(cand: Candidate, thetas: list[float]) -> None:
    """Replace the winner's value by the mean of the per-run estimates and its uncertainty by the
    Student-t interval of that mean, t_(0.975, n-1) S / sqrt(n) (eq. 6 applied to the parameter),
    combined in quadrature with the linearised interval of the mean-input fit (the model error: the
    residual left at the optimum as noise), when the mean stays in the plausible range."""
    th = np.array(thetas)
    n = th.size
    c = cand.coord
    if n < 2 or c is None or not np.all(np.isfinite(th)):
        return
    mean = float(th.mean())
    half = t_critical(n) * float(th.std(ddof=1)) / math.sqrt(n)
    cand.per_run = [c.value(x) for x in th]
    if not c.tlo <= mean <= c.thi:
        add_detail(cand, f"per-run estimates average {c.value(mean):.4g}, outside the plausible range: mean-input "
                         "fit kept")
        return
    first = c.value(cand.theta)
    cand.theta = mean
    # the runs' scatter and the model error (the linearised interval from the residual left at the
    # optimum, which grows with the unexplained, structural part) together
    model_error = cand.u_theta if math.isfinite(cand.u_theta) else 0.0
    half = math.sqrt(half * half + model_error * model_error)
    cand.u_theta = half
    cand.effect.params[c.name] = c.value(mean)
    cand.effect.set_interval(c.name, c.value_uncertainty(mean, half), c.value_uncertainty(mean, model_error))
    cand.significant = bool(abs(mean) > half)
    add_detail(cand, f"value and 95 % interval from {n} per-run replays (the mean-input fit gave {first:.4g})")


TIE_DISTANCE = 0.5


def distance(obj: Objective, a: dict, b: dict, channels: list[str] | None = None) -> float:
    """RMS difference of two model responses in units of the channels' standard errors (on `channels`,
    default all compared): below TIE_DISTANCE the data cannot tell the two apart."""
    if channels is not None:
        ra, rb = obj.channel_residual(a), obj.channel_residual(b)
        d = np.concatenate([ra[c] - rb[c] for c in channels])
    else:
        d = obj.residual(a) - obj.residual(b)
    return float(np.sqrt(np.mean(d * d)))


def equivalents(obj: Objective, winner: Candidate, cands: list[Candidate]) -> list[tuple[Candidate, float]]:
    """Other plausible candidates whose fitted response is indistinguishable from the winner's."""
    out = []
    for c in cands:
        if c is winner or not c.plausible or not c.predicts:
            continue
        dist = distance(obj, winner.outputs, c.outputs)
        if dist < TIE_DISTANCE:
            out.append((c, dist))
    return out


def told_apart(ctx: Context, winner: Candidate, cands: list[Candidate], confounded: float) -> list[Candidate]:
    """The eligible candidates of the winner's kind the data cannot tell from it: substitutes for it (the
    changes the two make to the outputs, beyond what the nuisance adjustments absorb, correlate by at
    least `confounded`, the workflow's confounding level) that the cross-validation does not separate
    from it (the paired fold test, crossval.p_better_than, over the same folds against the same model,
    does not find the winner's left-out-run predictions better at ALPHA). A rolling resistance and a
    bearing drag on a straight stop differ only by their dependence on the wheel load; a scale of one
    wheel angle and the inverse scale of the other wheel on its axle differ only by the axle's rolling
    radius, which the nuisance adjustment re-fits: the runs then cannot say which one it is."""
    if winner.cv is None or not winner.outputs:
        return []
    obj = ctx.objective
    m0 = normalised(obj, ctx.outputs)

    def change(c):
        d = normalised(obj, c.outputs) - m0
        return obj.nuisance.project_direction(d) if obj.nuisance is not None else d

    dw = change(winner)
    nw = float(np.linalg.norm(dw))
    out = []
    for c in cands:
        if c is winner or c.kind != winner.kind or not c.eligible or c.cv is None or not c.outputs or nw <= 0.0:
            continue
        dc = change(c)
        nc = float(np.linalg.norm(dc))
        if nc > 0.0 and abs(float(dw @ dc)) / (nw * nc) >= confounded \
                and p_better_than(winner.cv, c.cv) >= ALPHA:
            out.append(c)
    return out


def rank(cands: list[Candidate]) -> list[Candidate]:
    """Eligible candidates first, then the others; each by the held-out loss it removes (Candidate.score)."""
    return sorted(cands, key=lambda c: (not c.eligible, not c.plausible, c.score))


def evidence_strength(delta: float) -> str:
    """Kass-Raftery wording for an IC difference between two candidates."""
    d = abs(delta)
    if d < 2:
        return "indistinguishable on this manoeuvre"
    if d < 6:
        return "positive evidence"
    if d < 10:
        return "strong evidence"
    return "very strong evidence"


# ------------------------------------------------------------------------- joint fit of model effects
JOINT_SIMS = 10              # simulations per joint fit at most
JOINT_DIFF = 0.1             # finite-difference step, relative to the coordinate (floor: 5 % of its range)
JOINT_STEP = 0.01            # a joint step shorter than this share of every coordinate's scale: converged


@dataclass
class Member:
    """One model effect of a joint fit: its name, coordinate, the other (fixed) parameters, its
    starting coordinate and its sensitivity column there (a single fit's secant)."""
    name: str
    coord: Coord
    others: dict
    theta: float
    J: np.ndarray

    @classmethod
    def of(cls, cand: "Candidate") -> "Member":
        return cls(cand.effect.name, cand.coord, {k: v for k, v in cand.effect.values().items()
                                                  if k != cand.coord.name}, float(cand.theta), cand.J)

    def effect(self, th: float) -> Effect:
        return Effect(self.name, {self.coord.name: self.coord.value(th), **self.others})


@dataclass
class JointFit:
    """Model effects fitted together by re-simulation (fit_joint): the coordinates, the residual's
    Jacobian there (columns: members), the outputs, the cost, the 95 % half-widths (linearised, residual
    left as noise) and the correlation of the sensitivities; `requested` the value a member asks for
    beyond its plausible range (None when inside)."""
    members: list[Member]
    theta: np.ndarray
    J: np.ndarray
    outputs: dict
    raw: dict
    cost: float
    u_theta: np.ndarray
    corr: np.ndarray
    sims: int
    requested: list
    note: str = ""

    def effects(self, theta: np.ndarray | None = None) -> list[Effect]:
        th = self.theta if theta is None else theta
        return [m.effect(float(t)) for m, t in zip(self.members, th)]


def _lstsq_step(J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step -argmin |r + J d| (a tiny ridge keeps near-collinear columns finite)."""
    A = J.T @ J
    A = A + 1e-9 * np.trace(A) / len(A) * np.eye(len(A))
    return -np.linalg.solve(A, J.T @ r)


SEGMENTS = 6                 # time segments per channel in the block jackknife


def joint_uncertainty(obj: Objective, J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """95 % half-widths of the fitted coordinates (columns of J) and the correlation of their estimates,
    from the residual `r` left at the optimum (module docstring, "Uncertainty"): per coordinate, the
    larger of the sandwich and the block jackknife, in quadrature with the discrepancy bound."""
    m = J.shape[1]
    A = J.T @ J
    try:
        Ai = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return np.full(m, math.inf), np.full((m, m), math.nan)
    n = r.size // len(obj.channels)
    meat = np.zeros((m, m))
    for i in range(len(obj.channels)):
        rc, jc = r[i * n:(i + 1) * n], J[i * n:(i + 1) * n]
        meat += _tau(rc) * float(rc @ rc) / n * (jc.T @ jc)
    cov = Ai @ meat @ Ai
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(sd, sd) if np.all(sd > 0) else np.full((m, m), math.nan)
    half = 1.96 * np.maximum(sd, _jackknife_sd(J, r, len(obj.channels) * SEGMENTS))
    return np.sqrt(half ** 2 + _discrepancy(J, r, len(obj.channels), Ai) ** 2), corr


def _discrepancy(J: np.ndarray, r: np.ndarray, channels: int, Ai: np.ndarray) -> np.ndarray:
    """Per coordinate, the largest change of the fitted value that the residual left beyond the data's own
    uncertainty could cause, had it the shape of the coordinate's sensitivity on every channel: channel c
    leaves |d_c|^2 = n max(0, mean(r_c^2) - 1 - 2 sqrt(2 tau_c / n)) (normalised residuals: mean(r_c^2)
    is about 1, within twice its own scatter over n / tau_c independent samples, where the model sits
    within the data's uncertainty), and d moves the values by Ai J' d, at most
    sum_c |d_c| |J_c Ai e_k|. A model that misses the data by a structural residual on the channels
    that carry a value cannot pin the value closer than that, however consistent the misfit is (a
    different tyre law biases the stiffness the same way in every block of the jackknife)."""
    n = r.size // channels
    out = np.zeros(J.shape[1])
    for i in range(channels):
        rc, jc = r[i * n:(i + 1) * n], J[i * n:(i + 1) * n]
        excess = float(np.mean(rc * rc)) - 1.0 - 2.0 * math.sqrt(2.0 * _tau(rc) / n)
        if excess > 0.0:
            out += math.sqrt(n * excess) * np.linalg.norm(jc @ Ai, axis=0)
    return out


def _jackknife_sd(J: np.ndarray, r: np.ndarray, blocks: int) -> np.ndarray:
    """Standard deviation of the fitted coordinates by the delete-one-block jackknife, linearised at the
    optimum: leaving block b out moves theta by -(J'J - J_b'J_b)^-1 (J'r - J_b'r_b). Noise makes the
    blocks agree to within the sandwich's scatter; a structural residual that the fit leans on makes
    them disagree, and the interval widens with it."""
    m = J.shape[1]
    A = J.T @ J
    edges = np.linspace(0, r.size, blocks + 1).astype(int)
    g = J.T @ r
    moves = []
    for b in range(blocks):
        jb, rb = J[edges[b]:edges[b + 1]], r[edges[b]:edges[b + 1]]
        rest = A - jb.T @ jb
        if np.linalg.cond(rest) > 1e12:       # the block holds all of a coordinate's information
            continue
        moves.append(-np.linalg.solve(rest, g - jb.T @ rb))
    if len(moves) < 2:
        return np.zeros(m)
    dev = np.array(moves) - np.mean(moves, axis=0)
    return np.sqrt((len(moves) - 1) / len(moves) * np.sum(dev * dev, axis=0))


def sensitivity_correlation(J: np.ndarray) -> np.ndarray:
    """Cosines between the Jacobian's columns (structural.correlations' measure)."""
    nrm = np.linalg.norm(J, axis=0)
    nrm[nrm == 0] = 1.0
    return (J.T @ J) / np.outer(nrm, nrm)


def fit_joint(ctx: Context, fixed: list[Effect], members: list[Member], start: tuple[dict, dict] | None,
              budget: int = JOINT_SIMS) -> JointFit:
    """The members fitted together over their coordinates with the effects `fixed` in the model:
    Gauss-Newton from the members' starting coordinates (`start`: (raw, reported outputs) there, else
    simulated) with the single fits' sensitivity columns, the Jacobian updated after every simulation
    with the change it saw (Broyden's rank-one update), a step that costs more halved. When the steps
    stall (shorter than JOINT_STEP of every coordinate, or halved thrice) the Jacobian is taken afresh by
    finite differences at the best point (one simulation per member): a secant carried from a single
    fit far away can stall the search far from the joint minimum. Converged when a step on a fresh
    Jacobian stalls; coordinates stay in the plausible range. At most `budget` simulations."""
    obj, rp = ctx.objective, ctx.replayer
    th0 = np.array([m.theta for m in members], dtype=float)
    lo = np.array([m.coord.tlo for m in members])
    hi = np.array([m.coord.thi for m in members])
    span = hi - lo
    J = np.column_stack([m.J for m in members]).astype(float)
    sims = 0
    note = ""

    def simulate(th: np.ndarray):
        effects = [*fixed, *(m.effect(float(t)) for m, t in zip(members, th))]
        raw = rp.simulate(ctx.inputs, effects, fit=True)
        return raw, rp.reported(raw, ctx.inputs.t, effects)

    if start is None:
        raw, out = simulate(th0)
        sims += 1
    else:
        raw, out = start
    best = (th0, obj.residual(out), out, raw)
    cur = best
    shrink, fresh = 1.0, False

    def run(th: np.ndarray):
        nonlocal sims, note
        sims += 1
        try:
            raw_n, out_n = simulate(th)
        except RtsimError as exc:           # the model cannot run there
            note = f"a joint step failed to simulate ({str(exc).splitlines()[0][:80]})"
            return None
        return (th, obj.residual(out_n), out_n, raw_n)

    while sims < budget:
        d = _lstsq_step(J, best[1]) * shrink
        thn = np.clip(best[0] + d, lo, hi)
        scale = np.maximum(np.abs(best[0]), 0.02 * span)
        if np.all(np.abs(thn - best[0]) <= JOINT_STEP * scale) or shrink < 0.2:
            if fresh:
                break                       # converged with a Jacobian taken at the best point
            # the step stalls on a Jacobian carried from elsewhere: finite differences at the best point
            for k in range(len(members)):
                if sims >= budget:
                    break
                h = JOINT_DIFF * max(abs(best[0][k]), 0.05 * span[k])
                if best[0][k] + h > hi[k]:
                    h = -h
                th = best[0].copy()
                th[k] += h
                p = run(th)
                if p is not None:
                    J[:, k] = (p[1] - best[1]) / h
                    if float(p[1] @ p[1]) < float(best[1] @ best[1]):
                        best = p
            fresh, shrink, cur = True, 1.0, best
            continue
        p = run(thn)
        if p is None:
            shrink *= 0.5
            continue
        s_ = thn - cur[0]
        J = J + np.outer((p[1] - cur[1]) - J @ s_, s_) / float(s_ @ s_)
        cur, fresh = p, False
        if float(p[1] @ p[1]) < float(best[1] @ best[1]):
            best, shrink = p, 1.0
        else:
            shrink *= 0.5
    th, r, out, raw = best
    # a coordinate held on its bound while the unconstrained step points beyond it: the data ask for more
    free = th + _lstsq_step(J, r)
    requested = [m.coord.value(float(f)) if (abs(f - float(np.clip(f, a, b))) > 0.05 * sp
                                             and (not m.coord.inverse or f > 0)) else None
                 for m, f, a, b, sp in zip(members, free, lo, hi, span)]
    u, _ = joint_uncertainty(obj, J, r)
    return JointFit(members, th, J, out, raw, float(np.mean(r * r)), u, sensitivity_correlation(J), sims,
                    requested, note)


def joint_run_estimate(ctx: Context, fixed: list[Effect], fit: JointFit, i: int) -> np.ndarray:
    """Run i's own estimate of the joint coordinates (run_estimate in several dimensions): the model with
    the joint values replayed with run i's inputs at the model's step, one Gauss-Newton step against run i."""
    effects = [*fixed, *fit.effects()]
    inp = ctx.replayer.inputs(ctx.bench, run=i)
    raw = ctx.replayer.simulate(inp, effects)
    out = ctx.replayer.reported(raw, inp.t, effects)
    return fit.theta + _lstsq_step(fit.J, ctx.objective.residual_to_run(out, i))


def joint_member(ctx: Context, fit: JointFit, k: int, base_outputs: dict) -> Candidate:
    """Member k of a joint fit judged beyond the others (channel_evidence): the joint outputs against
    `base_outputs`, the model without member k (the others at their own fit), one value counted; its
    interval is the joint one (the others' uncertainty included)."""
    m = fit.members[k]
    base = Context(ctx.bench, ctx.objective, ctx.replayer, ctx.inputs, ctx.effects, base_outputs, {},
                   ctx.objective.cost(base_outputs), ctx.n_runs, ctx.deviations)
    th = float(fit.theta[k])
    cand = _finish(base, m.effect(th), "model", 1, fit.outputs, fit.J[:, k].copy(), th, m.coord, fit.sims,
                   fit.requested[k], "")
    cand.u_theta = float(fit.u_theta[k])
    u = m.coord.value_uncertainty(th, cand.u_theta)
    cand.effect.set_interval(m.coord.name, u, u)
    cand.significant = bool(abs(th) > cand.u_theta) and math.isfinite(cand.u_theta)
    cand.raw = fit.raw
    return cand
