"""Independent field-data simulators for the validation benchmark (issue 30).

Several structurally different vehicle simulators written from textbook equations (`sims`: a planar
two-track car without roll, the same with a roll degree of freedom, a pitch-plane longitudinal car; a
tanh friction-circle and a brush tyre law), the car's numbers they use (`vehicle`), run-to-run scatter
and sensor imperfections of field loggers (`scatter`), the benchmark's cases and their seeded tuning /
held-out split (`cases`), and a case's runs as the CSV files `rtsim validate` reads, cached on disk
(`generate`). The package shares no model code with rtsim's vehicle: it reads only the numbers of the
vehicle config (TOML, the tyre property file) and of `rtsim describe` (a dict given to it); it imports
nothing from rtsim at all (a test checks its imports).
"""
