"""Independent field-data simulators for the validation benchmark (issue 30).

Several structurally different vehicle simulators written from textbook equations (`sims`: a planar
two-track car without roll, the same with a roll degree of freedom, a pitch-plane longitudinal car; two
tyre laws in `tyres`), run-to-run scatter and sensor imperfections of field loggers (`scatter`), the
benchmark's cases and their seeded tuning / held-out split (`cases`), and the CSV files `rtsim validate`
reads (`write`). The package shares no model code with rtsim's vehicle: it reads only the numbers of the
vehicle config (TOML, the tyre property file) and of `rtsim describe` (a dict given to it); it imports
nothing from rtsim.vehicle, rtsim.mbs or the validation workflow (a test checks the import graph).
"""
