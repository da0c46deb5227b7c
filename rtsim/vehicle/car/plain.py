"""The car's plain parameters: the vehicle file's keys (dotted, as a batch overrides them) whose values
the build turns into numbers of the compiled arrays without changing the model's topology (its
coordinates, constraints, the pattern of its mass matrix) or the corner fits (which read the
hardpoints, the suspension types, static camber and toe, the travel range and whether [eps] steers the
pivots). A model of a config that differs from a built one in these keys only is made on the built one,
in one of two ways, each declared here with the arrays the key reaches:

- ``IN_PLACE``: the built model with copies of the arrays the key reaches, computed by the code the
  build computes them with (rtsim.vehicle.car.build.apply_in_place: the chassis body's share of the mass
  matrix and gravity vector, rtsim.mbs Mechanism.with_bodies; the static wheel loads and the suspension's
  tables and parameters; the aero parameters; the config, which each run's start reads its parts'
  parameters from), every other array shared: a fraction of a millisecond;
- ``ON_KEPT``: built again on the built one's corner fits and symbolic analysis (rtsim.vehicle.car.build,
  ``reuse``): the same code computes every value, a third of a fresh build's time.

Either way the model equals a fresh build's bit for bit (tests/test_batch_plain.py).

Each pattern (fnmatch: ``*`` spans dots) with the arrays it reaches; any key not matched -- hardpoints,
suspension, travel_m, rigid, static_camber_rad, static_toe_rad, cg_m, driven_axle, tyres.*, [eps] itself
or its driver_input, interface, effects -- rebuilds the vehicle from scratch."""
from __future__ import annotations

from fnmatch import fnmatchcase
from functools import lru_cache

IN_PLACE = "in place"       # the built model's affected arrays computed anew, the rest shared
ON_KEPT = "on the kept analysis"    # built again on the built model's corner fits and symbolic analysis

#: pattern -> (how it is applied: IN_PLACE or ON_KEPT, what it changes in the built model or "per run": read
#: from the config by each run's start)
PLAIN: dict[str, tuple[str, str]] = {
    "chassis.mass_kg": (IN_PLACE, "mass matrix, gravity vector, static wheel loads, spring preload tables"),
    "chassis.inertia_kgm2": (IN_PLACE, "mass matrix"),
    "chassis.ixz_kgm2": (IN_PLACE, "mass matrix"),
    "*.unsprung_mass_kg": (ON_KEPT, "mass matrix, gravity vector, static wheel loads"),
    "*.wheel_spin_inertia_kgm2": (ON_KEPT, "mass matrix"),
    "*.pivot_inertia_kgm2": (ON_KEPT, "mass matrix (EPS: the pivots; steer-by-wire: reflected to the rack)"),
    "*.spring.stiffness_n_per_m": (IN_PLACE, "spring tables"),
    "*.spring.free_length_m": (IN_PLACE, "spring tables"),
    "*.spring.bump_stop_*": (IN_PLACE, "spring tables"),
    "*.spring.damping_*": (IN_PLACE, "damper tables"),
    "*.spring.spring_table": (IN_PLACE, "spring tables"),
    "*.spring.damper_table": (IN_PLACE, "damper tables"),
    "*.anti_roll_bar_n_per_m": (IN_PLACE, "suspension parameters"),
    "*.travel_stop_*": (IN_PLACE, "suspension parameters"),
    "*.compliance_steer_*": (IN_PLACE, "suspension parameters"),
    "*.anti_pitch_arm_m": (IN_PLACE, "suspension parameters"),
    "*.anti_roll_arm_m": (IN_PLACE, "suspension parameters"),
    "aero.*": (IN_PLACE, "aero parameters"),
    "steering.*": (ON_KEPT, "steering inertias in the mass matrix; the steering's parameters per run"),
    "eps.*": (ON_KEPT, "EPS inertias and constraint constants; the EPS's parameters per run"),
    "brakes.*": (IN_PLACE, "per run (the brake's parameters)"),
    "powertrain.*": (IN_PLACE, "per run (the powertrain's parameters and its rolling start)"),
    "sensors.channels.*": (IN_PLACE, "per run (the sensor model's parameters)"),
}

#: keys matched by a pattern of PLAIN that do change the topology
NOT_PLAIN: tuple[str, ...] = ("eps.driver_input",)


def in_place(keys) -> bool:
    """Whether every one of the dotted keys is a plain parameter applied in place (IN_PLACE)."""
    return all(key not in NOT_PLAIN and _how(key) == IN_PLACE for key in keys)


@lru_cache(maxsize=1024)
def _how(key: str) -> str | None:
    for pattern, (how, _) in PLAIN.items():
        if fnmatchcase(key, pattern):
            return how
    return None
