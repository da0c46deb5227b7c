"""The car's plain parameters: the vehicle file's keys (dotted, as a batch overrides them) whose values
the build turns into numbers of the compiled arrays without changing the model's topology (its
coordinates, constraints, the pattern of its mass matrix) or the corner fits (which read the
hardpoints, the suspension types, static camber and toe, the travel range and whether [eps] steers the
pivots). A model of a config that differs from a built one in these keys only is built again on the
built one's corner fits and symbolic analysis (rtsim.vehicle.car.build, ``reuse``): the same code
computes every value, so it equals a fresh build bit for bit, in about a third of the time.

Each pattern (fnmatch: ``*`` spans dots) with the arrays it reaches; any key not matched -- hardpoints,
suspension, travel_m, rigid, static_camber_rad, static_toe_rad, cg_m, driven_axle, tyres.*, [eps] itself
or its driver_input, interface, effects -- rebuilds the vehicle from scratch."""
from __future__ import annotations

#: pattern -> what it changes in the built model (or "per run": read from the config by each run's start)
PLAIN: dict[str, str] = {
    "chassis.mass_kg": "mass matrix, gravity vector, static wheel loads, spring preload tables",
    "chassis.inertia_kgm2": "mass matrix",
    "chassis.ixz_kgm2": "mass matrix",
    "*.unsprung_mass_kg": "mass matrix, gravity vector, static wheel loads",
    "*.wheel_spin_inertia_kgm2": "mass matrix",
    "*.pivot_inertia_kgm2": "mass matrix (EPS: the pivots; steer-by-wire: reflected to the rack)",
    "*.spring.stiffness_n_per_m": "spring tables",
    "*.spring.free_length_m": "spring tables",
    "*.spring.bump_stop_*": "spring tables",
    "*.spring.damping_*": "damper tables",
    "*.anti_roll_bar_n_per_m": "suspension parameters",
    "*.travel_stop_*": "suspension parameters",
    "*.compliance_steer_*": "suspension parameters",
    "*.anti_pitch_arm_m": "suspension parameters",
    "*.anti_roll_arm_m": "suspension parameters",
    "aero.*": "aero parameters",
    "steering.*": "steering inertias in the mass matrix; the steering's parameters per run",
    "eps.*": "EPS inertias and constraint constants; the EPS's parameters per run",
    "brakes.*": "per run (the brake's parameters)",
    "powertrain.*": "per run (the powertrain's parameters and its rolling start)",
    "sensors.channels.*": "per run (the sensor model's parameters)",
}

#: keys matched by a pattern of PLAIN that do change the topology
NOT_PLAIN: tuple[str, ...] = ("eps.driver_input",)
