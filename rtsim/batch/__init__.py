"""Batch runs: a plan (scenarios x vehicles x a parameter grid or random sample x seeds) expanded into
run specs, each run to one results row (parameters, named metrics, verdict, wall time, error), on a
local process pool or a Ray cluster, journalled as rows arrive so an interrupted batch resumes.

    plan.py      the plan file (TOML, validated through rtsim.configfile)
    expand.py    plan -> run specs (grid / seeded random sample, dotted-path overrides, run ids)
    inputs.py    what a run reads (every file, nested ones included, hashed into its id) and what its
                 seed draws
    metrics.py   the library of named metrics over a run's columns (rtsim.channels names, SI units)
    run.py       one run spec -> one result row; never raises
    executors.py the local process pool and the Ray executor
    results.py   the JSON-lines journal (resume), the final Parquet and CSV tables
    progress.py  the ETA from completed runs' own wall times
    report.py    the HTML summary: metrics against parameters, the failures
    cli.py       `rtsim batch PLAN.toml`
"""
