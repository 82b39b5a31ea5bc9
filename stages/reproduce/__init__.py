"""`make reproduce*`: generate data, run rfir and every baseline on the same splits, write tables.

The targets (rcs, rcs-po, wideband, rssi, extrapolation, edit, ablation, measured; targets.py) declare their steps as
data on a Plan (plan.py: command lines, inputs, outputs, code versions) and a table whose cells read
the steps' results later (tables.py). The Snakemake workflow workflow/Snakefile turns each step into
a rule and each table into a rule that writes OUT/<target>.md, .csv, .png and .json (with the wall
time of every step from Snakemake's benchmark files). Sizes of the full and the quick variant:
configs/reproduce.toml; the quick variant (physical-optics data, few iterations, one baseline
epoch) checks the whole chain in minutes and its numbers are not the project's results.
`python -m rfir_stages.reproduce` holds the helpers the workflow calls (see __main__.py).
"""
