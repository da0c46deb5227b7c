"""Robustness checks: command sequences drawn inside a vehicle's DBC ranges, run offline through the
service's vehicle step, with the outcome of each ride (a model failure, a fall, finite state, an energy
bound). rtsim.robustness.commands reads the command space and draws sequences; rtsim.robustness.harness
runs them; rtsim.robustness.bench is ``rtsim bench --suite fuzz``."""
