"""The four-wheel car as a kind of vehicle (rtsim.vehicle.registry): the X-by-wire car and the car with
electric power steering ([eps]) are both this kind; what differs between them is their config."""
from __future__ import annotations

import numpy as np

from ..registry import Demo, OfflineRun, VehicleKind
from .plain import NOT_PLAIN, PLAIN, in_place

EPS_DEMO_SCENARIO = "step_steer_80kph"      # the EPS ECU's manoeuvre


def channel_names(channels) -> dict:
    """The channel dictionary's names by kind (`rtsim describe`)."""
    return {"sensors": list(channels.sensor_names), "commands": list(channels.command_names),
            "state": list(channels.state_names)}


class CarKind(VehicleKind):
    name = "car"
    default_scenario = "hil_flat"
    not_for = {
        "eigen": "it computes a two-wheeler's modes in straight running (weave, wobble, capsize)",
        "statics": "it computes a two-wheeler at rest with the rider on",
    }

    def load(self, data, path):
        from .config import load_vehicle
        return load_vehicle(path, {k: v for k, v in data.items() if k != "kind"})

    def build(self, opened):
        from .build import build_vehicle
        return build_vehicle(opened.config, opened.base)

    plain_parameters = tuple(PLAIN)
    not_plain = NOT_PLAIN

    def rebuild(self, opened, built, changed=None):
        """The car made on the built one (rtsim.vehicle.car.plain): its arrays applied in place when every
        changed key is declared so, else built again on its corner fits and symbolic analysis."""
        from .build import apply_in_place, build_vehicle
        if changed is not None and in_place(changed) and opened.base == built.base:
            return apply_in_place(opened.config, built.model)
        return build_vehicle(opened.config, opened.base, reuse=built.model)

    def describe(self, opened) -> dict:
        from rtsim.road.model import make_plane

        from .describe import describe
        from .sim import VehicleSim

        model = opened.model
        info = describe(model, VehicleSim(model, make_plane(), 1e-3))
        cfg = model.config
        front, rear = cfg.front.unsprung_mass_kg, cfg.rear.unsprung_mass_kg
        w = model.design_wheel_centre
        return {"name": info.pop("name"), "id": info.pop("id"), "kind": self.name, "file": str(opened.path),
                "n_coordinates": info.pop("n_coordinates"), "n_constraints": info.pop("n_constraints"),
                "n_dof": info.pop("n_dof"), "mass": info["mass"],
                "masses": {"chassis": cfg.chassis.mass_kg, "unsprung_fl": front, "unsprung_fr": front,
                           "unsprung_rl": rear, "unsprung_rr": rear},
                "geometry": {"wheelbase": info["wheelbase"], "track_front": info["track_front"],
                             "track_rear": info["track_rear"], "cg_height": info["cg_height"],
                             "cg_to_front_axle": info["cg_to_front_axle"],
                             "wheel_centres": [[float(x) for x in row] for row in w]},
                "channels": channel_names(model.channels), **info}

    def scenario_problem(self, opened, sc):
        if sc.two_wheeler:
            return "it is a two-wheeler's scenario ([rider] or [two_wheeler]); give a car's ([inputs] or a driver)"
        return None

    def random_elements(self, opened, sc) -> list[str]:
        """The seed draws the sensor model's noise (rtsim.vehicle.kit.sensor_model), which only the
        config's [sensors.channels.<name>] noise_std sets; nothing else of an offline run is random."""
        return [f"sensor noise on {name}" for name, spec in opened.config.sensors.channels.items()
                if spec.noise_std > 0.0]

    def run_offline(self, opened, sc, progress=None, seed=0) -> OfflineRun:
        from ..offline import run, sim_for

        driver = sc.driver()                # one for the start's brake command and the run (reset between)
        sim = sim_for(opened.model, sc, driver)
        res = run(sim, sc, progress, seed=seed, driver=driver)
        out = OfflineRun(res.columns, res.data, res.wall_s, res.steps, status="ok" if res.fault is None else "failed",
                         message="" if res.fault is None else res.fault.line(), fault=res.fault,
                         vehicle_id=sim.vm.config.id, channels=sim.vm.channels, scene=sim, step_s=res.step_s)
        dist = float(np.sum(np.hypot(np.diff(res.column("pos_x")), np.diff(res.column("pos_y")))))
        peak = float(res.column("speed").max()) if len(res.data) else 0.0
        out.line = (f"{sc.name}: {res.data[-1, 0] if len(res.data) else 0.0:g} s simulated in {res.wall_s:.2f} s "
                    f"({res.wall_s / max(res.steps, 1) * 1e6:.1f} us/step"
                    f"{f'; {res.compile_s:.0f} s compiling besides' if res.compile_s else ''}), distance {dist:.1f} m, "
                    f"peak speed {peak * 3.6:.1f} km/h, {len(res.data)} rows")
        return out

    def service_sim(self, opened, sc, dt, models, rider):
        from rtsim.road.config import load_road

        from .sim import VehicleSim

        key = opened.path.resolve()
        model = models.get(key)
        if model is None:
            model = models[key] = opened.model
        ini = sc.spec.initial
        sim = VehicleSim(model, load_road(sc.road_path), dt if dt is not None else sc.dt, brake_pressure=0.0,
                         position=(ini.x, ini.y), yaw=ini.yaw, speed=ini.speed)
        sim.user_inputs = opened.user_inputs
        sim.road_path = sc.road_path      # what the 3D scene draws besides the mesh (OpenDRIVE road marks)
        return sim

    def user_inputs(self, opened):
        """The car's user channels (rtsim.vehicle.car.inputs), full scales from its config: the throttle's
        wide-open angle, the brake actuator's maximum."""
        from .inputs import user_inputs

        cfg = opened.config
        return user_inputs(float(cfg.powertrain.throttle.max), float(cfg.brakes.actuator.max))

    def validation(self, opened):
        """The car's validation profile (rtsim.vehicle.car.validation), its sensor channels the config's."""
        from .validation import profile

        return profile(opened.config)

    def demo(self, opened) -> Demo:
        if opened.config.eps is not None:      # the EPS ECU closes the assist loop: lockstep, its manoeuvre
            return Demo("drivers.eps_demo", "lockstep", EPS_DEMO_SCENARIO, None, True)
        return Demo("drivers.ecu_demo")

    def fuzz_rig(self, opened, dt):
        from .fuzz import CarFuzzRig
        return CarFuzzRig(opened, dt)

    def drawing(self, opened):
        from .drawing import car_drawing
        return car_drawing(opened.config, opened.base)


KIND = CarKind()
