# One rule per step of PLAN (a stages/reproduce/plan.Plan with its inputs linked), included by a
# Snakefile that defines PLAN. Its params are what reruns a step: the command line (cmd) and the
# code version of the sources and configs the command reads (code; plan.CODE). Log and benchmark
# per step label under PLAN.out (logs/, benchmarks/).
import os
import sys
from pathlib import Path

from rfir_stages.reproduce.plan import code_version, rule_name

# Commands name `rfir` and `python`: those in config "bin", else beside the interpreter running Snakemake.
os.environ["PATH"] = str(config.get("bin", Path(sys.executable).parent)) + os.pathsep + os.environ.get("PATH", "")

_CODE_VERSIONS = {}   # per source list of plan.CODE, hashed once per invocation


def code_of(step):
    if step.code_files not in _CODE_VERSIONS:
        _CODE_VERSIONS[step.code_files] = code_version(step.code_files)
    return _CODE_VERSIONS[step.code_files]


def declared(paths):
    """Outputs: a path ending in "/" is a folder output."""
    return [directory(p.rstrip("/")) if p.endswith("/") else p for p in paths]


for _step in PLAN.steps.values():
    rule:
        name: rule_name(_step.label)
        input: [p.rstrip("/") for p in _step.inputs]     # a folder input: its path, no flag
        output: declared(_step.outputs)
        params: cmd=_step.command, code=code_of(_step)
        log: str(PLAN.log_path(_step.label))
        benchmark: str(PLAN.benchmark_path(_step.label))
        threads: _step.threads
        shell: "{params.cmd} > {log} 2>&1"
