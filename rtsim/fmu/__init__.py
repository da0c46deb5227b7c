"""FMI in rtsim: a controller FMU as a command source (mapping.py, controller.py) and the vehicle as an
FMI 3.0 co-simulation FMU (export.py, vehicle_slave.py). docs/fmu.md is the manual."""
