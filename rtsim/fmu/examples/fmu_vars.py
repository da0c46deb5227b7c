"""What the example controller FMUs (pi_speed.py, lane_keep.py) declare alike: their units, the independent
variable time, float inputs and outputs with units, and tunable parameters with their start values. Packed
into each FMU beside its script (rtsim.fmu.examples.build_example)."""
from pythonfmu3 import Fmi3Causality, Fmi3Variability, Float64
from pythonfmu3.unit import Unit

#: the units the examples use: name -> (factor to the base units, exponents)
UNITS = {"m/s": (1.0, {"m": 1, "s": -1}), "rad": (1.0, {"rad": 1}), "kPa": (1e3, {"kg": 1, "m": -1, "s": -2}),
         "mm": (1e-3, {"m": 1})}


def declare(slave, inputs: dict, outputs: dict, params: dict) -> None:
    """Register time, the inputs and outputs ({name: unit}, each starting at 0) and the tunable parameters
    ({name: start value}) of `slave`, and set them as its attributes."""
    slave.time = 0.0
    used = sorted(set(inputs.values()) | set(outputs.values()))
    slave.register_units([Unit(u, factor=UNITS[u][0], **UNITS[u][1]) for u in used])
    slave.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                    variability=Fmi3Variability.continuous))
    for causality, table in ((Fmi3Causality.input, inputs), (Fmi3Causality.output, outputs)):
        for name, unit in table.items():
            setattr(slave, name, 0.0)
            slave.register_variable(Float64(name, causality=causality, unit=unit,
                                            start=0.0 if causality == Fmi3Causality.input else None))
    for name, value in params.items():
        setattr(slave, name, value)
        slave.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                        variability=Fmi3Variability.tunable, start=value))
