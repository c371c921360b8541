"""`python -m pipelines.materialize GROUP [GROUP ...]`: materialise asset groups in order with a progress bar.

What `make demo` runs. Each group is one Dagster run of its group job (checks included) in the instance
under $DAGSTER_HOME, so the runs and their full logs are in the UI (`make dev`) afterwards; the terminal
shows a progress bar per group and warnings, and a text log per run goes to $TRAFFICLEARN_HOME/logs/.
The same as `dagster asset materialize --select group:GROUP`, which prints every log line instead.
"""

import argparse
import sys
import time

import dagster as dg

from pipelines.definitions import SYSTEMS, defs
from warehouse.storage import home


def group_jobs() -> dict[str, str]:
    """asset group -> the name of the job that materialises it (assets/<system>/__init__.py JOBS)."""
    return {j.selection.selected_groups[0]: j.name for s in SYSTEMS for j in s.JOBS}


def run(job: dg.JobDefinition, group: str, instance: dg.DagsterInstance) -> tuple[bool, str]:
    """Execute one job with the progress logger; (success, one line saying what happened)."""
    log_file = home() / "logs" / f"{time.strftime('%Y%m%dT%H%M%S')}_{group}.log"
    config = {"total_steps": len(job.graph.node_dict), "desc": group, "log_file": str(log_file)}
    t0 = time.perf_counter()
    result = job.execute_in_process(
        instance=instance, run_config={"loggers": {"progress": {"config": config}}}, raise_on_error=False
    )
    took = time.perf_counter() - t0
    if result.success:
        return True, f"{group}: {config['total_steps']} steps in {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"
    failed = [e.step_key for e in result.all_events if e.is_step_failure]
    return False, f"{group}: FAILED at {', '.join(failed) or 'run start'} after {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"


def main(argv: list[str] | None = None) -> int:
    groups = group_jobs()
    parser = argparse.ArgumentParser(prog="python -m pipelines.materialize", description=__doc__.splitlines()[0])
    parser.add_argument("groups", nargs="+", metavar="GROUP", help=f"asset groups in order: {', '.join(groups)}")
    args = parser.parse_args(argv)
    unknown = [g for g in args.groups if g not in groups]
    if unknown:
        parser.error(f"unknown group {', '.join(unknown)}; the groups are {', '.join(groups)}")
    with dg.DagsterInstance.get() as instance:
        for group in args.groups:
            ok, line = run(defs.resolve_job_def(groups[group]), group, instance)
            print(line, flush=True)
            if not ok:
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
