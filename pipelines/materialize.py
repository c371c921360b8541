"""`python -m pipelines.materialize GROUP [GROUP ...]`: materialise asset groups in order with a progress bar.

What `make demo` runs. Each group is one Dagster run of its group job (checks included) in the instance
under $DAGSTER_HOME, so the runs and their full logs are in the UI (`make dev`) afterwards; the terminal
shows a progress bar per group and warnings, and a text log per run goes to $TRAFFICLEARN_HOME/logs/.
The same as `dagster asset materialize --select group:GROUP`, which prints every log line instead.
`--config-json '{"ops": {STEP: {"config": {...}}}}'` configures steps as `dagster asset materialize` does; each
group's run takes the steps it has, and a failure is one line (Dagster's CLI prints its whole stack).
"""

import argparse
import json
import sys
import time

import dagster as dg

from pipelines.definitions import SYSTEMS, defs
from warehouse.storage import home


def group_jobs() -> dict[str, str]:
    """asset group -> the name of the job that materialises it (assets/<system>/__init__.py JOBS)."""
    return {j.selection.selected_groups[0]: j.name for s in SYSTEMS for j in s.JOBS}


def run(job: dg.JobDefinition, group: str, instance: dg.DagsterInstance, ops: dict | None = None) -> tuple[bool, str]:
    """Execute one job with the progress logger and the steps' config `ops`; (success, one line saying what happened)."""
    log_file = home() / "logs" / f"{time.strftime('%Y%m%dT%H%M%S')}_{group}.log"
    config = {"total_steps": len(job.graph.node_dict), "desc": group, "log_file": str(log_file)}
    t0 = time.perf_counter()
    try:
        result = job.execute_in_process(
            instance=instance, run_config={"loggers": {"progress": {"config": config}}, "ops": ops or {}}, raise_on_error=False
        )
    except dg.DagsterInvalidConfigError as e:  # a wrong field or type: Dagster's message lists every error over many lines
        return False, f"{group}: invalid config: " + "; ".join(err.message.replace("\n", " ") for err in e.errors)
    took = time.perf_counter() - t0
    if result.success:
        return True, f"{group}: {config['total_steps']} steps in {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"
    failed = [e.step_key for e in result.all_events if e.is_step_failure]
    return False, f"{group}: FAILED at {', '.join(failed) or 'run start'} after {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"


def main(argv: list[str] | None = None) -> int:
    groups = group_jobs()
    parser = argparse.ArgumentParser(prog="python -m pipelines.materialize", description=__doc__.splitlines()[0])
    parser.add_argument("groups", nargs="+", metavar="GROUP", help=f"asset groups in order: {', '.join(groups)}")
    parser.add_argument("--config-json", default="{}", metavar="JSON", help='steps\' config, e.g. \'{"ops": {"flight_ingest": {"config": {"source_path": "my.csv"}}}}\'')
    args = parser.parse_args(argv)
    unknown = [g for g in args.groups if g not in groups]
    if unknown:
        parser.error(f"unknown group {', '.join(unknown)}; the groups are {', '.join(groups)}")
    try:
        ops = json.loads(args.config_json).get("ops", {})
    except (json.JSONDecodeError, AttributeError) as e:
        parser.error(f"--config-json: not a JSON object with an 'ops' key ({e})")
    jobs = {g: defs.resolve_job_def(groups[g]) for g in args.groups}
    strangers = sorted(set(ops) - {step for job in jobs.values() for step in job.graph.node_dict})
    if strangers:
        parser.error(f"--config-json names steps {', '.join(strangers)} that the groups {', '.join(args.groups)} do not run")
    with dg.DagsterInstance.get() as instance:
        for group, job in jobs.items():
            ok, line = run(job, group, instance, {k: v for k, v in ops.items() if k in job.graph.node_dict})
            print(line, flush=True)
            if not ok:
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
