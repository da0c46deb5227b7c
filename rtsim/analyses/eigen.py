"""Stability of a two-wheeler in straight running: eigenvalues, mode shapes and names against speed,
from the full nonlinear model linearised numerically (rtsim.analyses.linearise).

What is in the analysis: the multibody model (masses, inertias, geometry, the wheels' gyroscopics) and
every force element of the vehicle file (rtsim.analyses.applied): slip tyres with their contact
deflections as first-order states (relaxation), the suspension springs and dampers (or the locked
suspension's rows), the steering damper, the chain, aero drag and lift; knife-edge wheels are rolling
constraints instead. The linearisation of a damper whose compression and rebound rates differ is the
mean of the two (the central difference across the kink at zero speed).

The operating point at each speed is a relative equilibrium of the full model, solved for: upright,
straight, the frame's height and pitch and the suspension travels at their sag under the loads of that
speed (aero lift and drag, the drive's squat or anti-squat), each wheel's spin rate and longitudinal
contact deflection at their steady slip, and the drive torque (rider's throttle, held constant in the
linearisation) that balances rolling resistance and drag. The speed is then a state like the others; its
mode (*speed*) is the slow decay of a speed change against drag.

The modes split exactly into in-plane and out-of-plane ones (the upright machine is mirror symmetric);
each is read out in physical quantities (roll, steer, yaw, lateral, pitch, bounce, the suspension
travels, the wheels' heights and spin rates, the forward speed, the tyres' deflections) and named:

- out of plane: *weave* (oscillatory, roll and yaw with the steer, below ~5 Hz), *wobble* (oscillatory,
  steer-dominated, above it), *capsize* (the slowest real, roll-dominated mode; a faster one, the frame
  rolling on the tyres' lateral compliance, is *roll*), *castering* (real, steer-dominated), and *front
  tyre lateral* / *rear tyre lateral* where a tyre's lateral deflection (as the slip angle v/sigma it
  carries) dominates the angles (the relaxation modes, near -V/sigma at speed) or the frame sways in yaw
  on the contacts' lateral stiffness (oscillatory, yaw-dominated; the tyre with the larger slip names it);
- in plane: *speed*, *front tyre longitudinal* / *rear tyre longitudinal* (the wheel's spin against the
  tyre's longitudinal slip stiffness, and the longitudinal relaxation), *front hop* / *rear hop* (a wheel
  moving on its suspension more than the frame above it), and the frame's *bounce* (its vertical motion
  at the two axles in phase: node outside the wheelbase) and *pitch* (in opposition: node between them).
A mode changes stability where its real part changes sign; those speeds are refined by bisection.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rtsim.errors import ModelError
from rtsim.mbs.model import gravity
from rtsim.vehicle.motorcycle.build import MotorcycleModel, combine, straight_running_velocity
from rtsim.vehicle.motorcycle.config import Body
from rtsim.vehicle.motorcycle.layout import D_FORK, D_PITCH, D_SWING, D_Z, NAMES, NDOF, POINTS, VECTORS

from .applied import SLIP_NAMES, AppliedForces
from .linearise import Equations, reduced_matrix

OP_ITERATIONS = 30
OP_TOL = 1e-9          # residual (m/s^2, m/s) of a converged operating point
OP_STALL = 1e-3        # ... or a last step below this fraction of the difference steps
OP_ACCEPT = 1e-4       # largest residual accepted after a stalled solve

EZ = np.array([0.0, 0.0, 1.0])
OUT_OF_PLANE = ("roll", "steer", "yaw", "lateral", "v_front", "v_rear")
IN_PLANE = ("pitch", "bounce", "fork", "swingarm", "front_wheel", "rear_wheel", "speed", "spin_front", "spin_rear",
            "u_front", "u_rear")
WOBBLE_HZ = 5.0
DOMINANT = 3.0      # one quantity names a mode when it exceeds the others by this factor


@dataclass
class Mode:
    name: str
    eigenvalue: complex
    shape: dict[str, complex]          # physical quantities, normalised to the largest angle-like entry

    @property
    def frequency_hz(self) -> float:
        return abs(self.eigenvalue.imag) / (2 * np.pi)


@dataclass
class SpeedResult:
    speed: float
    modes: list[Mode] = field(default_factory=list)
    operating: dict[str, float] = field(default_factory=dict)   # TwoWheelerLinearisation.operating

    def eigenvalues(self, exclude=("speed",)) -> np.ndarray:
        return np.array([m.eigenvalue for m in self.modes if m.name not in exclude])


class TwoWheelerLinearisation:
    """Linearise `mm` about straight running with the applied forces of its vehicle file (`applied`;
    rtsim.analyses.applied: tyres with their contact-deflection states, suspension, steering damper,
    chain, aero) and optionally `extra_forces(q, qd)`. `mu`: road friction scale of the tyres."""

    def __init__(self, mm: MotorcycleModel, extra_forces=None, applied: bool = True, mu: float = 1.0):
        self.mm = mm
        self.applied = AppliedForces(mm, mu) if applied else None
        n_aux = self.applied.n_slip if applied else 0
        self.eqs = Equations(mm.mech, extra_forces, self.applied, n_aux)
        self.nq = mm.mech.model.nq
        self.n_aux = n_aux
        self.operating: dict[str, float] = {}

    # ---- the operating point and its symmetries ----------------------------------------------------
    def _k(self, name: str) -> int:
        return int(self.mm.bike.idx[NAMES.index(name)])

    def _state(self, speed: float, p: np.ndarray) -> np.ndarray:
        """x = (q, qd, z) for the unknowns p of `operating_point` (module docstring)."""
        mm = self.mm
        dof = np.zeros(NDOF)
        dof[[D_Z, D_PITCH, D_FORK, D_SWING]] = p[:4]
        q = mm.coordinates(dof)
        if self.n_aux:
            omega_f, omega_r = p[4:6]
        else:
            omega_f, omega_r = speed / mm.config.front_wheel.radius_m, speed / mm.config.rear_wheel.radius_m
        qd = straight_velocity(mm, q, speed, omega_f, omega_r)
        z = np.zeros(self.n_aux)
        if self.n_aux:
            z[0], z[2] = p[6:8]          # longitudinal deflections; lateral ones are zero upright
        return np.concatenate([q, qd, z])

    def _motion(self, x: np.ndarray, speed: float) -> np.ndarray:
        """The generator xi(x) of straight running at `speed` with the wheel spin rates of x."""
        qd = x[self.nq:2 * self.nq]
        rates = np.array([speed, qd[self._k("PHI_F")], qd[self._k("PHI_R")]])
        return self.symmetries(x)[:, [0, 3, 4]] @ rates

    def operating_point(self, speed: float, q: np.ndarray | None = None) -> np.ndarray:
        """The state x0 = (q, qd, z) of upright straight running at `speed` (m/s), a relative equilibrium
        of the full model: the frame's height and pitch, the fork and swingarm travel (static sag plus
        the load changes of drive, drag and aero lift), each wheel's spin rate and longitudinal contact
        deflection (the steady longitudinal slip), and the drive torque that holds the speed, by
        Gauss-Newton on f(x) - xi(x) = 0 together with the constraints. A given `q` skips the solve
        (straight running from that configuration, no drive)."""
        if q is not None:
            self.operating = {"speed_m_s": speed}
            if self.applied is not None:
                self.applied.drive = 0.0
            return np.concatenate([q, straight_running_velocity(self.mm, q, speed), np.zeros(self.n_aux)])
        cfg = self.mm.config
        p = np.zeros(5 + (4 if self.n_aux else 0))
        steps = [1e-6, 1e-6, 1e-6, 1e-6]
        if self.n_aux:
            p[:2], deflection = self._tyre_deflection_guess()
            steps = [min(1e-6, 1e-3 * deflection)] * 4      # well inside the contact
            p[4:6] = speed / cfg.front_wheel.radius_m, speed / cfg.rear_wheel.radius_m
            steps += [1e-6 * max(1.0, p[4]), 1e-6 * max(1.0, p[5]), 1e-7, 1e-7]
        steps.append(1e-3)
        steps = np.array(steps)

        def residual(pp):
            if self.applied is not None:
                self.applied.drive = pp[-1]
            x = self._state(speed, pp)
            return np.concatenate([self.eqs.rates(x) - self._motion(x, speed), self.eqs.manifold(x)])

        r = residual(p)
        for _ in range(OP_ITERATIONS):
            if np.linalg.norm(r) < OP_TOL:
                break
            jac = np.array([(residual(p + e) - residual(p - e)) / (2 * e[i])
                            for i, e in enumerate(np.diag(steps))]).T
            dp = np.linalg.lstsq(jac, -r, rcond=None)[0]
            for alpha in (1.0, 0.5, 0.25, 0.125):      # damped: never accept a growing residual
                r_new = residual(p + alpha * dp)
                if np.linalg.norm(r_new) < np.linalg.norm(r):
                    break
            p, r = p + alpha * dp, r_new
            if np.max(np.abs(alpha * dp / steps)) < OP_STALL:
                break                # converged to the rounding of the forces (very stiff tyres)
        r = residual(p)              # leaves the drive torque of p in the force model
        if np.linalg.norm(r) >= OP_ACCEPT:
            raise ModelError(f"{cfg.id}: no straight running at {speed} m/s (residual {np.linalg.norm(r):.3g})")
        x0 = self._state(speed, p)
        # the frame's pose from the design position (pitch positive nose down), the suspension travels
        self.operating = {"speed_m_s": speed, "height_m": p[0], "pitch_rad": p[1], "fork_travel_m": p[2],
                          "swingarm_rotation_rad": p[3], "drive_torque_nm": p[-1]}
        if self.n_aux:
            self.applied(x0[:self.nq], x0[self.nq:2 * self.nq], x0[2 * self.nq:])
            loads = self.applied.loads()
            if np.any(loads <= 0.0):
                raise ModelError(f"{cfg.id}: a wheel leaves the road at {speed} m/s (loads {loads} N)")
            self.operating.update(spin_front_rad_s=p[4], spin_rear_rad_s=p[5], load_front_n=loads[0],
                                  load_rear_n=loads[1])
        return x0

    def _tyre_deflection_guess(self) -> tuple[np.ndarray, float]:
        """((height, pitch) of the frame with each tyre deflected by its static load (m, rad), the smaller
        deflection (m)): the start of the solve (at the design position the tyres just touch the road)."""
        cfg = self.mm.config
        wheels = [Body(mass_kg=w.mass_kg, cg_m=(x, w.radius_m)) for w, x in
                  ((cfg.front_wheel, cfg.geometry.wheelbase_m), (cfg.rear_wheel, 0.0))]
        mass, cg, _i = combine(cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork, *wheels)
        share = cg[0] / cfg.geometry.wheelbase_m
        g = -gravity(self.mm.mech.model)[2]            # m/s^2, the model's
        d_f = share * mass * g / cfg.tyres.front.radial_stiffness_n_per_m
        d_r = (1.0 - share) * mass * g / cfg.tyres.rear.radial_stiffness_n_per_m
        return np.array([-0.5 * (d_f + d_r), (d_f - d_r) / cfg.geometry.wheelbase_m]), min(d_f, d_r)

    def _slices(self, names):
        for n in names:
            k = self.mm.bike.idx[NAMES.index(n)]
            if k >= 0:
                yield n, slice(k, k + 3)

    def symmetries(self, x0: np.ndarray) -> np.ndarray:
        """Columns: translation x, y; yaw about the vertical; each wheel's spin about its axle (front,
        rear). The contact deflections are invariant."""
        n = self.nq
        q, qd = x0[:n], x0[n:2 * n]
        size = 2 * n + self.n_aux
        cols = []
        for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
            s = np.zeros(size)
            for _name, sl in self._slices(POINTS):
                s[sl] = axis
            cols.append(s)
        s = np.zeros(size)
        for _name, sl in self._slices(POINTS + VECTORS):
            s[sl] = _cross(EZ, q[sl])
            s[n:][sl] = _cross(EZ, qd[sl])
        cols.append(s)
        for axle, vecs, spin in (("E_U", ("B_F", "C_F"), "PHI_F"), ("V", ("B_R", "C_R"), "PHI_R")):
            s = np.zeros(size)
            ka = self._k(axle)
            a, ad = q[ka:ka + 3], qd[ka:ka + 3]
            for _name, sl in self._slices(vecs):
                s[sl] = _cross(a, q[sl])
                s[n:][sl] = _cross(ad, q[sl]) + _cross(a, qd[sl])
            s[self._k(spin)] = 1.0
            cols.append(s)
        return np.array(cols).T

    def mirror(self) -> np.ndarray:
        """Signs (2 nq + n_aux) of the reflection y -> -y of a state perturbation: points and in-plane
        vectors flip their y component, the axles (v, e_U, lateral) their x and z components, the steer
        angle and the lateral contact deflections their sign. The upright two-wheeler is mirror
        symmetric, so each mode is either in plane (even) or out of plane (odd)."""
        sign = np.ones(self.nq)
        for name, sl in self._slices(POINTS + VECTORS):
            sign[sl] = (-1.0, 1.0, -1.0) if name in ("V", "E_U") else (1.0, -1.0, 1.0)
        sign[self._k("DELTA")] = -1.0
        aux = np.array([1.0, -1.0] * (self.n_aux // 2))
        return np.concatenate([sign, sign, aux])

    # ---- physical read-out of a state perturbation -------------------------------------------------
    def readout(self, x0: np.ndarray, dx: np.ndarray) -> dict[str, complex]:
        """Linear read-out of a (complex) state perturbation in physical quantities: rear-frame roll, yaw,
        pitch (rad), steer (rad), lateral and bounce displacement of the pivot (m), fork and swingarm
        travel (m), the wheel centres' heights (m), forward speed (m/s), each wheel's absolute spin rate (rad/s)
        and, with slip tyres, the contact deflections (m, SLIP_NAMES)."""
        mm, n = self.mm, self.nq
        g = lambda x, name: x[self._k(name):][:3]   # noqa: E731
        dq, dqd, dz = dx[:n], dx[n:2 * n], dx[2 * n:]
        eps = mm.config.caster_rad
        x_axis = np.cos(eps) * g(dq, "E1") - np.sin(eps) * g(dq, "H_AX")
        # the wheels' spin angles are measured from the frame (rear) and the fork (front), which pitch
        # with the frame: the absolute spin rate adds the pitch rate (both about the lateral axis)
        pitch_rate = -(np.cos(eps) * g(dqd, "E1") - np.sin(eps) * g(dqd, "H_AX"))[2]
        out = {
            "roll": g(dq, "V")[2], "yaw": -g(dq, "V")[0], "pitch": -x_axis[2],
            "steer": g(dq, "DELTA")[0], "lateral": g(dq, "P")[1], "bounce": g(dq, "P")[2],
            "fork": g(dq, "ZETA")[0], "swingarm": g(dq, "THETA")[0] * mm.design.swingarm_length,
            "front_wheel": g(dq, "W_F")[2], "rear_wheel": g(dq, "W_R")[2],
            "speed": g(dqd, "P")[0], "spin_front": g(dqd, "PHI_F")[0] + pitch_rate,
            "spin_rear": g(dqd, "PHI_R")[0] + pitch_rate,
        }
        for name, v in zip(SLIP_NAMES, dz):
            out[name] = v
        return out

    # ---- modes -------------------------------------------------------------------------------------
    def _name(self, x0: np.ndarray, lam: complex, shape: dict[str, complex], odd: bool) -> str:
        """Name a mode from its eigenvalue, its symmetry and its physical shape (module docstring)."""
        mag = {k: abs(v) for k, v in shape.items()}
        tyres = self.mm.config.tyres
        if odd:
            mech = max(mag["roll"], mag["steer"], mag["yaw"], 1e-300)
            if self.n_aux:
                # the slip angle each tyre's lateral deflection carries (v / sigma_alpha)
                a_f = mag["v_front"] / tyres.front.relaxation_length_lat_m
                a_r = mag["v_rear"] / tyres.rear.relaxation_length_lat_m
                oscillating = abs(lam.imag) > 1e-6 * max(1.0, abs(lam))
                # a deflection dominating the angles, or the frame swaying in yaw on the contacts'
                # lateral stiffness (K_alpha / sigma_alpha)
                sway = oscillating and mag["yaw"] > 2.0 * max(mag["steer"], mag["roll"])
                if max(a_f, a_r) > DOMINANT * mech or sway:
                    return "front tyre lateral" if a_f >= a_r else "rear tyre lateral"
            oscillating = abs(lam.imag) > 1e-6 * max(1.0, abs(lam))
            steer_led = mag["steer"] > DOMINANT * mag["roll"]
            if oscillating:
                return "wobble" if steer_led and abs(lam.imag) / (2 * np.pi) > WOBBLE_HZ else "weave"
            return "castering" if steer_led else "capsize"
        # in plane: compare velocities (m/s): the forward speed, each tyre's longitudinal slip velocity
        # (its rolling speed less the forward speed, or the rate of its deflection) and the vertical
        # motion of the wheels and of the frame above them
        n = self.nq
        xs = {k: x0[self._k(k)] for k in ("P", "W_F", "W_R")}
        frame_f = shape["bounce"] - shape["pitch"] * (xs["W_F"] - xs["P"])
        frame_r = shape["bounce"] - shape["pitch"] * (xs["W_R"] - xs["P"])
        heave = abs(lam) * max(mag["front_wheel"], mag["rear_wheel"], abs(frame_f), abs(frame_r))
        slip = [0.0, 0.0]
        if self.n_aux:
            speed = x0[n + self._k("P")]
            for i, (spin, u) in enumerate((("spin_front", "u_front"), ("spin_rear", "u_rear"))):
                rolling = speed / x0[n + self._k("PHI_F" if i == 0 else "PHI_R")]    # m
                slip[i] = max(abs(rolling * shape[spin] - shape["speed"]), abs(lam) * mag[u])
        if max(slip) > max(mag["speed"], heave):
            return "front tyre longitudinal" if slip[0] >= slip[1] else "rear tyre longitudinal"
        if mag["speed"] > heave:
            return "speed"
        # a wheel hops when it moves more than the frame above it, on its suspension (a locked suspension
        # has no hop: the machine bounces and pitches on its tyres)
        hop_f = mag["front_wheel"] / max(abs(frame_f), 1e-300) if mag["fork"] > 0.5 * mag["front_wheel"] else 0.0
        hop_r = mag["rear_wheel"] / max(abs(frame_r), 1e-300) if mag["swingarm"] > 0.5 * mag["rear_wheel"] else 0.0
        if max(hop_f, hop_r) > 1.0:
            return "front hop" if hop_f >= hop_r else "rear hop"
        # the frame's vertical motion at the two axles: in phase (node outside the wheelbase) is bounce,
        # in opposition (node between the axles) is pitch
        return "bounce" if (frame_f * np.conj(frame_r)).real > 0 else "pitch"

    def modes(self, speed: float, q: np.ndarray | None = None) -> SpeedResult:
        """The modes at `speed` (m/s), slowest first (one of each conjugate pair)."""
        x0 = self.operating_point(speed, q)
        sym = self.symmetries(x0)
        a, basis = reduced_matrix(self.eqs, x0, sym, lambda x: self._motion(x, speed))
        lam, vec = np.linalg.eig(a)
        mirror = self.mirror()
        out = SpeedResult(speed, operating={k: float(v) for k, v in self.operating.items()})
        for k in np.argsort(lam.real):
            if lam[k].imag < -1e-9 * max(1.0, abs(lam[k])):
                continue            # one of each conjugate pair
            dx = basis @ vec[:, k]
            odd = np.linalg.norm(dx - mirror * dx) > np.linalg.norm(dx + mirror * dx)
            shape = self.readout(x0, dx)
            out.modes.append(Mode(self._name(x0, lam[k], shape, odd), complex(lam[k]), _normalise(shape)))
        # the slowest real roll mode is the capsize; a faster one (the frame rolling on the tyres'
        # lateral compliance) is a roll mode
        capsize = [m for m in out.modes if m.name == "capsize"]
        for m in capsize[:-1]:
            m.name = "roll"
        return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors (np.cross costs ~30 us a call; the symmetries take hundreds per mode set)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _normalise(shape: dict[str, complex]) -> dict[str, complex]:
    angles = max(abs(shape[k]) for k in ("roll", "steer", "yaw", "pitch"))
    ref = max(angles, 1e-300)
    return {k: complex(v / ref) for k, v in shape.items()}


def straight_velocity(mm: MotorcycleModel, q: np.ndarray, speed: float, omega_front: float,
                      omega_rear: float) -> np.ndarray:
    """qd of the upright two-wheeler at q running straight ahead at `speed` (m/s) along its heading with
    the wheels spinning at omega_front, omega_rear (rad/s) about their axles."""
    qd = straight_running_velocity(mm, q, speed)
    for axle, vecs, spin, omega in (("E_U", ("B_F", "C_F"), "PHI_F", omega_front),
                                    ("V", ("B_R", "C_R"), "PHI_R", omega_rear)):
        w = omega * mm.group(q, axle)
        for name in vecs:
            k = mm.bike.idx[NAMES.index(name)]
            qd[k:k + 3] = np.cross(w, q[k:k + 3])
        qd[mm.bike.idx[NAMES.index(spin)]] = omega
    return qd

