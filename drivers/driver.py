"""A complete driver: open-loop profiles for some channels, closed-loop followers for others.

`Driver.step(t, state)` returns the input array (layout `drivers.base.INPUT_NAMES`) for time t and the
vehicle state (layout `drivers.base.DriverView`); it is one call of the compiled kernel `driver_step`, which
evaluates every packed profile, then lets the speed follower overwrite throttle and brake and the
path follower overwrite the steering-wheel angle. A real-time loop written in numba calls
`driver_step(d.packed, d.speed, d.path, d.flags, t, state, out)` itself with the same arrays.

Followers that are not used are replaced by inert placeholders (flag 0), so the kernel has a single
signature whatever the combination.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from rtsim.jit import kernel

from .base import I_BRAKE, I_STEER, I_THROTTLE, INPUT_INDEX, INPUT_NAMES, NINPUT, NSTATE
from .path_follower import PathFollower, path_follower, path_follower_step
from .path_follower import reset as reset_path
from .profiles import Packed, Profile, eval_profiles, pack
from .speed_follower import SpeedFollower, speed_follower, speed_follower_step
from .speed_follower import reset as reset_speed

F_SPEED = 0   # flags[F_SPEED] = 1: the speed follower drives throttle and brake
F_PATH = 1    # flags[F_PATH] = 1: the path follower drives the steering-wheel angle
NFLAG = 2


@kernel
def driver_step(packed, speed, path, flags, t, state, out):
    """Fill out[0:NINPUT] at time t for the vehicle state."""
    eval_profiles(packed, t, out)
    if flags[F_SPEED] != 0:
        speed_follower_step(speed, t, state, out)
    if flags[F_PATH] != 0:
        path_follower_step(path, t, state, out)


_IDLE: dict = {}


def _idle(which: str):
    """A copy of the idle follower (its arrays copied) that stands in for a missing one; built once per
    process (a follower's construction takes a few tenths of a ms)."""
    f = _IDLE.get(which)
    if f is None:
        f = _IDLE[which] = speed_follower([0.0], [0.0]) if which == "speed" else path_follower([0.0, 1.0], [0.0, 0.0])
    return type(f)(*(a.copy() for a in f))


class Driver:
    """Profiles per channel plus optional speed and path followers.

    profiles: {input name: Profile} (or an already packed `Packed`); channels without a profile and
    without a follower stay 0. A channel driven by a follower must not also have a profile.
    """

    def __init__(self, profiles: Mapping[str, Profile] | Packed | None = None,
                 speed: SpeedFollower | None = None, path: PathFollower | None = None):
        profiles = {} if profiles is None else profiles
        if isinstance(profiles, Packed):
            self.packed = profiles
            names = [n for i, n in enumerate(INPUT_NAMES)
                     if profiles.ch_first[i + 1] > profiles.ch_first[i]]
        else:
            for name in profiles:
                if name not in INPUT_INDEX:
                    raise ValueError(f"unknown input channel {name!r}; allowed: {', '.join(INPUT_NAMES)}")
            self.packed = pack(profiles, NINPUT)
            names = list(profiles)
        if speed is not None:
            clash = {INPUT_NAMES[I_THROTTLE], INPUT_NAMES[I_BRAKE]} & set(names)
            if clash:
                raise ValueError(f"{', '.join(sorted(clash))}: driven by the speed follower and a profile")
        if path is not None and INPUT_NAMES[I_STEER] in names:
            raise ValueError(f"{INPUT_NAMES[I_STEER]}: driven by the path follower and a profile")
        self.flags = np.zeros(NFLAG, dtype=np.int64)
        self.flags[F_SPEED] = speed is not None
        self.flags[F_PATH] = path is not None
        self.speed = speed if speed is not None else _idle("speed")
        self.path = path if path is not None else _idle("path")
        self.out = np.zeros(NINPUT)
        self._state = np.zeros(NSTATE)
        #: the scenario's controller FMU mapping (rtsim.fmu.mapping) or a command source in its place
        #: (rtsim.fmu.controller), which the service's loop runs beside this driver
        #: (rtsim.service.controller); None: none
        self.controller = None

    def reset(self) -> None:
        """Forget the followers' controller state (integrators, tracked path index, rate limits)."""
        reset_speed(self.speed)
        reset_path(self.path)
        self.out[:] = 0.0

    def step(self, t: float, state: np.ndarray | None = None) -> np.ndarray:
        """The inputs at time t (a view of a preallocated array, overwritten by the next call)."""
        driver_step(self.packed, self.speed, self.path, self.flags, float(t),
                    self._state if state is None else state, self.out)
        return self.out

    @property
    def car_loop(self):
        """The compiled offline loop of a car driven by this driver (drivers.car_loop.car_offline_loop)."""
        from .car_loop import car_offline_loop
        return car_offline_loop

    @property
    def closed_loop(self) -> bool:
        return bool(self.flags.any())
