"""Fault injection: the catalogue (catalog), the spec a session is given (spec), the compiled table
(table) and the kernels the service's step runs (kernels). docs/faults.md is the manual."""
