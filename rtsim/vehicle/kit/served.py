"""The stages every served vehicle provides to the HIL service's compiled step (rtsim.service.kernel).

The service takes the vehicle as one named tuple ``v`` (what the vehicle's ``served()`` returns: its own
fields, named for what they hold, among them ``io.commands``, the command array the watchdog fills) and
calls, per step of ``h`` s:

- ``served_drive(v, state)``: the vehicle's own in-loop driver acts (a two-wheeler's rider, inside its
  step); returns True when the scenario's driver (drivers.driver, run by the service) is to write the
  commands the bus does not carry, after this stage wrote what that driver reads into ``state``
  (drivers.base DriverView: speed, position, yaw);
- ``served_user(v, usr, slot, bus_ok, takeover, work, h)``: the user's commands (rtsim.service.user_input)
  after the watchdog: ``usr`` one value per user channel of the vehicle (NaN: not driven), ``slot`` per
  channel the command slot it competes with (-1: none), ``bus_ok`` a bit mask (bit u: the bus holds a
  valid, timely command for channel u), ``takeover`` whether the user took over from the bus, ``work``
  the user source's own state (a two-wheeler's lean loop);
- ``served_advance(v, h)``: one step; returns its status (rtsim.mbs.model.OK or a failure);
- ``served_sensors(v, out)`` and ``served_observe(v, out)``: the sensor and the observer state channels;
- ``served_fault_arrays(v)``: the arrays actuator faults (rtsim.faults) write into, a tuple of float64
  arrays indexed as the vehicle sim's ``fault_actuators()`` declare (at least the command array).

These are declarations only. Each vehicle registers its implementations for the type of its own tuple
(numba ``overload`` with ``jit_options=JIT``, answering only when ``of_type(v, ItsTuple)``), in its own
module, imported where it builds that tuple; so a new vehicle brings its stages with it and the service
compiles one step per vehicle type with no branch or indirection in it. A vehicle of a type no module
registered is refused by numba when the step is compiled.
"""
from __future__ import annotations

#: numba options of every stage implementation (the kernels' own: no runtime, rtsim.jit)
JIT = {"_nrt": False}


def of_type(v, cls) -> bool:
    """Whether the numba type ``v`` is the named tuple ``cls`` (a vehicle's served tuple)."""
    return getattr(v, "instance_class", None) is cls


def served_drive(v, state):
    """The vehicle's own in-loop driver; True when the scenario's driver is to act (see the module docstring)."""


def served_user(v, usr, slot, bus_ok, takeover, work, h):
    """The user's commands for the step of h s (see the module docstring)."""


def served_advance(v, h):
    """One step of h s; returns the step's status (rtsim.mbs.model.OK or a failure)."""


def served_sensors(v, out):
    """The sensor channels, as the vehicle's sensors report them, into out."""


def served_observe(v, out):
    """The observer state channels into out."""


def served_fault_arrays(v):
    """The arrays actuator faults write into (see the module docstring)."""
