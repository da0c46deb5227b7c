"""The validation workflow (`rtsim validate`): from repeated field runs of one manoeuvre to a named
missing effect, added to the model, with the gap shown shrinking (the seed paper's methodology,
sec. 2.1 and 5, turned into a tool).

Modules, one job each: data (load and check runs), signals (resampling, wheel speeds), align
(repetitions on one grid), stats (Student-t band, eq. 6), replay (mean inputs into the model),
residuals (where the model leaves the band), identify (fit and rank candidate effects), configwrite
(new vehicle config + diff), verdict (what was found, per channel, what was turned down and why), report
(report.html, plots, summary.json), workflow (the iterative loop), cli (`rtsim validate`).
"""
