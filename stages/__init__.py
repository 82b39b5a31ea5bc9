"""rfir stages: one package per stage (simulate, calibrate, geom, rf_fit, predict, ...).

Each stage exposes `run(...)`, takes a progress reporter, never parses arguments and never prints.
"""
