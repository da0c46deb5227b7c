"""The two-wheeler as a kind of vehicle (rtsim.vehicle.registry): the sport motorcycle and the Whipple
benchmark bicycle are both this kind; what differs between them is their config."""
from __future__ import annotations

import math

from ..car.kind import channel_names
from ..registry import Demo, OfflineRun, VehicleKind

DEMO_DURATION = 20.0      # s of simulated time: the figure-eight's two circles and straights


class TwoWheelerKind(VehicleKind):
    name = "two_wheeler"
    default_scenario = "motorcycle_hil"
    not_for = {
        "feel": "it measures a car's electric power steering (torque against lateral acceleration, motor "
                "current); a two-wheeler has neither rack nor assist motor",
    }

    def load(self, data, path):
        from .config import load_motorcycle
        return load_motorcycle(path, data)

    def build(self, opened):
        from .build import build_motorcycle
        return build_motorcycle(opened.config, opened.base)

    #: every key: a rebuild takes nothing of the built model but its symbolic analysis, which the builder's
    #: compile takes only for the same topology (a knife-edge tyre model, a locked suspension, a massless
    #: body: computed afresh)
    plain_parameters = ("*",)

    def rebuild(self, opened, built, changed=None):
        from .build import build_motorcycle
        return build_motorcycle(opened.config, opened.base, reuse=built.model)

    def describe(self, opened) -> dict:
        from rtsim.channels import two_wheeler_channels

        from .offline import mass_centre

        mm = opened.model
        cfg = mm.config
        m, x, z = mass_centre(mm)
        wb = cfg.geometry.wheelbase_m
        masses = {name: b.mass_kg for name, b in (("rear_frame", cfg.rear_frame), ("rider", cfg.rider),
                                                  ("swingarm", cfg.swingarm), ("upper_fork", cfg.upper_fork),
                                                  ("lower_fork", cfg.lower_fork)) if b is not None}
        masses.update(front_wheel=cfg.front_wheel.mass_kg, rear_wheel=cfg.rear_wheel.mass_kg)
        nq, nc = mm.mech.model.nq, mm.mech.model.nc
        return {"name": cfg.name, "id": cfg.id, "kind": self.name, "file": str(opened.path),
                "n_coordinates": nq, "n_constraints": nc, "n_dof": nq - nc, "mass": m, "masses": masses,
                "geometry": {"wheelbase": wb, "track_front": 0.0, "track_rear": 0.0, "cg_height": z,
                             "cg_to_front_axle": wb - x,
                             "wheel_centres": [[wb, 0.0, cfg.front_wheel.radius_m], [0.0, 0.0, cfg.rear_wheel.radius_m]],
                             "caster": math.radians(cfg.geometry.caster_deg), "trail": float(cfg.trail)},
                "channels": channel_names(two_wheeler_channels()),
                "wheel_radius_front": cfg.front_wheel.radius_m, "wheel_radius_rear": cfg.rear_wheel.radius_m,
                "tyre_model": cfg.tyres.model, "rider": cfg.rider is not None}

    def scenario_problem(self, opened, sc):
        if not sc.two_wheeler:
            return "it is a car's scenario; give a two-wheeler's ([rider] or [two_wheeler])"
        return None

    def random_elements(self, opened, sc) -> list[str]:
        """Nothing: the two-wheeler's sensors are ideal and its rider deterministic (the offline ride
        takes no seed)."""
        return []

    def run_offline(self, opened, sc, progress=None, seed=0) -> OfflineRun:
        from .offline import CHANNELS, prepare, run, scene_source

        ride, sc = prepare(opened.path, sc, mm=opened.model)
        res = run(ride, sc, progress)
        out = OfflineRun(res.columns, res.data, res.wall_s, res.steps, res.status, res.message, res.fault,
                         res.summary, vehicle_id=ride.sim.mm.config.id, channels=CHANNELS,
                         scene=scene_source(ride.sim.mm), step_s=res.step_s)
        out.line = (f"{sc.name}: {res.summary.get('simulated_s')} s simulated in {res.wall_s:.2f} s, "
                    f"{len(res.data)} rows")
        return out

    def service_sim(self, opened, sc, dt, models, rider):
        """On the flat road of the scenario (the two-wheeler's tyres run on the plane z = 0 only), its
        friction scale the tyres' road friction; with the scenario's rider unless ``rider`` is False."""
        from .rider import RiderPar
        from rtsim.errors import ConfigError
        from rtsim.road.config import FlatRoadConfig, read_road_config

        from .config import refuse_effects
        from .hil import TwoWheelerHil
        from .ride import tyre_lean_ratio
        from .sim import static_pose

        road = read_road_config(sc.road_path)
        if not isinstance(road, FlatRoadConfig) or road.height != 0.0:
            raise ConfigError(f"{sc.path}: road {sc.road_path}: a two-wheeler runs on a flat road at height 0 only")
        if rider and sc.spec.rider is None:
            raise ConfigError(f"{sc.path}: no [rider] section for the two-wheeler {opened.path.name} (serve it "
                              f"with --rider off for a controller on the bus to ride it)")
        key = (opened.path.resolve(), self.name)
        if key not in models:
            cfg, base = opened.config, opened.base
            refuse_effects(cfg, opened.path, "the service")
            mm = opened.model
            models[key] = (mm, (base / cfg.interface.dbc).resolve(), static_pose(mm)[0])
        mm, dbc, q = models[key]
        ini = sc.spec.initial
        r = None
        if rider:
            r = sc.rider()
            if "tyre_lean" not in sc.spec.rider.model_fields_set:      # the vehicle's own tyres' crown correction
                r.par[RiderPar.TYRE_LEAN] = tyre_lean_ratio(mm)
        sim = TwoWheelerHil(mm, dbc, q, dt if dt is not None else sc.dt, speed=ini.speed, x=ini.x, y=ini.y,
                            yaw=ini.yaw, rider=r, mu=road.mu)
        sim.user_inputs = opened.user_inputs
        return sim

    def user_inputs(self, opened):
        """The two-wheeler's user channels (rtsim.vehicle.motorcycle.inputs), the brakes' full scales from
        its masses, wheels and calipers."""
        from .inputs import user_inputs

        return user_inputs(opened.config)

    def validation(self, opened):
        """The two-wheeler's validation profile (rtsim.vehicle.motorcycle.validation)."""
        from .validation import PROFILE

        return PROFILE

    def demo(self, opened) -> Demo:
        return Demo("drivers.rider_assist_demo", "lockstep", None, DEMO_DURATION, True)

    def fuzz_rig(self, opened, dt):
        from .fuzz import TwoWheelerFuzzRig
        return TwoWheelerFuzzRig(opened, dt)

    def drawing(self, opened):
        from .drawing import two_wheeler_drawing
        return two_wheeler_drawing(opened.config)


KIND = TwoWheelerKind()
