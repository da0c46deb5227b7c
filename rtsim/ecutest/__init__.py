"""ECU test catalogues: `rtsim test CATALOG.toml` (docs/ecu-tests.md)."""
