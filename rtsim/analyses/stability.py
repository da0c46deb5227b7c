"""The stability sweep of a two-wheeler: modes at each speed of a grid, the speeds where a mode changes
stability (refined by bisection to 1e-6 m/s), JSON out and a root-locus figure (`rtsim eigen`)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .eigen import SpeedResult, TwoWheelerLinearisation

BISECT_TOL = 1e-6     # m/s
CONTINUITY = 1e-3     # 1/s: |real part| on both sides of a refined crossing
ZOOM = 60.0           # 1/s: the root locus's view when faster (tyre) modes exist


@dataclass
class Crossing:
    mode: str
    speed: float           # m/s
    becomes: str           # "stable" or "unstable" with increasing speed


def speed_grid(text: str) -> np.ndarray:
    """'a:b:step' (inclusive ends) or a comma list, m/s."""
    if ":" in text:
        a, b, step = (float(x) for x in text.split(":"))
        if step <= 0 or b < a:
            raise ValueError(f"--speeds {text!r}: need start <= stop and step > 0")
        return np.round(np.arange(a, b + 0.5 * step, step), 12)
    return np.array([float(x) for x in text.split(",")])


def _worst(result: SpeedResult, name: str) -> float | None:
    re = [m.eigenvalue.real for m in result.modes if m.name == name]
    return max(re) if re else None


def sweep(lin: TwoWheelerLinearisation, speeds: np.ndarray) -> tuple[list[SpeedResult], list[Crossing]]:
    results = [lin.modes(float(v)) for v in speeds]
    crossings = []
    names = sorted({m.name for r in results for m in r.modes} - {"speed"})
    for name in names:
        for r0, r1 in zip(results, results[1:]):
            a, b = _worst(r0, name), _worst(r1, name)
            if a is None or b is None or (a < 0) == (b < 0):
                continue
            lo, hi, flo, fhi = r0.speed, r1.speed, a, b
            while hi - lo > BISECT_TOL:
                mid = 0.5 * (lo + hi)
                fm = _worst(lin.modes(mid), name)
                if fm is None:
                    break
                if (fm < 0) == (flo < 0):
                    lo, flo = mid, fm
                else:
                    hi, fhi = mid, fm
            # a real crossing is continuous; a jump is a mode changing its name (two real roots
            # joining into an oscillation)
            if hi - lo <= BISECT_TOL and abs(flo) + abs(fhi) < CONTINUITY:
                crossings.append(Crossing(name, 0.5 * (lo + hi), "stable" if b < 0 else "unstable"))
    return results, sorted(crossings, key=lambda c: c.speed)


def as_dict(vehicle: str, results: list[SpeedResult], crossings: list[Crossing]) -> dict:
    def mode(m):
        lam = m.eigenvalue
        zeta = -lam.real / abs(lam) if abs(lam) > 0 else 0.0
        return {"name": m.name, "real_1_s": lam.real, "imag_rad_s": lam.imag, "frequency_hz": m.frequency_hz,
                "damping_ratio": zeta,
                "shape": {k: {"magnitude": abs(v), "phase_deg": float(np.degrees(np.angle(v)))}
                          for k, v in m.shape.items()}}
    return {"vehicle": vehicle, "axes": "ISO 8855; roll positive right side down, steer positive left",
            "speeds_m_s": [r.speed for r in results],
            "modes": [{"speed_m_s": r.speed, "operating_point": r.operating, "modes": [mode(m) for m in r.modes]}
                      for r in results],
            "stability_changes": [{"mode": c.mode, "speed_m_s": c.speed, "becomes": c.becomes} for c in crossings]}


def write_json(path: str | Path, data: dict) -> None:
    Path(path).write_text(json.dumps(data, indent=1))


def root_locus(results: list[SpeedResult], crossings: list[Crossing], title: str, path: str | Path) -> None:
    """Eigenvalues in the complex plane, coloured by speed, one marker per mode name; and real parts
    against speed with the stability changes marked."""
    from matplotlib.figure import Figure

    from .figures import DPI

    fig = Figure(figsize=(11, 4.8))
    ax, ax2 = fig.subplots(1, 2)
    names = sorted({m.name for r in results for m in r.modes})
    markers = {name: "osd^v<>pPX*hH8+x"[i % 16] for i, name in enumerate(names)}
    vmin, vmax = results[0].speed, results[-1].speed
    sc = None
    for name in names:
        pts = [(r.speed, m.eigenvalue) for r in results for m in r.modes if m.name == name]
        v = np.array([p[0] for p in pts])
        lam = np.array([p[1] for p in pts])
        sc = ax.scatter(lam.real, lam.imag, c=v, cmap="viridis", vmin=vmin, vmax=vmax, s=12,
                        marker=markers[name], label=name)
        ax.scatter(lam.real, -lam.imag, c=v, cmap="viridis", vmin=vmin, vmax=vmax, s=4, marker=markers[name])
        ax2.plot(v, lam.real, markers[name], ms=3, label=name)
    ax.axvline(0, color="k", lw=0.6)
    fastest = min(m.eigenvalue.real for r in results for m in r.modes)
    if fastest < -ZOOM:          # tyre modes at -V/sigma: keep the vehicle's modes readable
        ax.set_xlim(-ZOOM, None)
        ax.set_ylim(-2 * ZOOM, 2 * ZOOM)
        ax2.set_ylim(-ZOOM, None)
        ax.set_title(f"faster modes (real part < -{ZOOM:g}/s) off the axes", fontsize=8)
    ax.set_xlabel("real part (1/s)")
    ax.set_ylabel("imaginary part (rad/s)")
    ax.legend(fontsize=7)
    if sc is not None:
        fig.colorbar(sc, ax=ax, label="speed (m/s)")
    ax2.axhline(0, color="k", lw=0.6)
    for c in crossings:
        ax2.axvline(c.speed, color="r", lw=0.6, ls="--")
        ax2.annotate(f"{c.mode} {c.speed:.3f}", (c.speed, 0), fontsize=7, rotation=90, va="bottom")
    ax2.set_xlabel("speed (m/s)")
    ax2.set_ylabel("real part (1/s)")
    ax2.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
