"""`make reproduce*`: generate data, run rfir and every baseline on the same splits, write tables.

    python -m rfir_stages.reproduce TARGET... [--quick] [--data DIR] [--out DIR] [--force]

TARGET: rcs, wideband, rssi, extrapolation, edit, ablation, or all. Each target writes
OUT/<target>.md, OUT/<target>.csv and OUT/<target>.png (MAE per method and row) and records the
wall time of every step in OUT/times.json; steps whose outputs exist are not run again (--force
reruns them). --quick: reduced sizes (physical-optics data, few iterations, short baseline
budgets) that check the whole chain in minutes; its numbers are not the project's results.
"""
