"""`python -m pipelines.materialize GROUP [GROUP ...]`: materialise asset groups in order with a progress bar.

What `make demo` runs. Each group is one Dagster run of its group job (checks included) in the instance
under $DAGSTER_HOME (default $TRAFFICLEARN_HOME/dagster), so the runs and their full logs are in the UI (`make dev`) afterwards; the terminal
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

from assets.profiles import default_profile
from pipelines.definitions import SYSTEMS, defs
from pipelines.instance import InstanceError, dagster_home
from warehouse.storage import home


def group_jobs() -> dict[str, str]:
    """asset group -> the name of the job that materialises it (assets/<system>/__init__.py JOBS)."""
    return {j.selection.selected_groups[0]: j.name for s in SYSTEMS for j in s.JOBS}


def run(job: dg.JobDefinition, group: str, instance: dg.DagsterInstance, ops: dict | None = None) -> tuple[bool, str]:
    """Execute one job with the progress logger and the steps' config `ops`; (success, one line saying what happened)."""
    log_file = home() / "logs" / f"{time.strftime('%Y%m%dT%H%M%S')}_{group}.log"
    config = {"total_steps": len(job.graph.node_dict), "desc": group, "log_file": str(log_file)}
    t0 = time.perf_counter()
    result = job.execute_in_process(
        instance=instance, run_config={"loggers": {"progress": {"config": config}}, "ops": ops or {}}, raise_on_error=False
    )
    took = time.perf_counter() - t0
    if result.success:
        return True, f"{group}: {config['total_steps']} steps in {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"
    failed = [e.step_key for e in result.all_events if e.is_step_failure]
    return False, f"{group}: FAILED at {', '.join(failed) or 'run start'} after {took / 60:.1f} min (run {result.run_id[:8]}, log {log_file})"


def _ops(parser: argparse.ArgumentParser, text: str) -> dict:
    """The steps' config of --config-json; anything but {"ops": {...}} is refused (a config without its "ops" key
    would otherwise run on the defaults, the bundled data, and replace the user's tables)."""
    try:
        config = json.loads(text)
    except json.JSONDecodeError as e:
        parser.error(f"--config-json: not JSON ({e})")
    if not isinstance(config, dict) or set(config) - {"ops"} or not isinstance(config.get("ops", {}), dict):
        parser.error('--config-json: expected {"ops": {STEP: {"config": {...}}}}, got ' + text[:80])
    return config.get("ops", {})


def main(argv: list[str] | None = None) -> int:
    groups = group_jobs()
    parser = argparse.ArgumentParser(prog="python -m pipelines.materialize", description=__doc__.splitlines()[0])
    parser.add_argument("groups", nargs="+", metavar="GROUP", help=f"asset groups in order: {', '.join(groups)}")
    parser.add_argument("--config-json", default="{}", metavar="JSON", help='steps\' config, e.g. \'{"ops": {"flight_ingest": {"config": {"source_path": "my.csv"}}}}\'')
    args = parser.parse_args(argv)
    try:
        default_profile()  # the configs' profile default; a misspelt TRAFFICLEARN_PROFILE would fail the first run's steps
    except ValueError as e:
        parser.error(str(e))
    unknown = [g for g in args.groups if g not in groups]
    if unknown:
        parser.error(f"unknown group {', '.join(unknown)}; the groups are {', '.join(groups)}")
    ops = _ops(parser, args.config_json)
    jobs = {g: defs.resolve_job_def(groups[g]) for g in args.groups}
    strangers = sorted(set(ops) - {step for job in jobs.values() for step in job.graph.node_dict})
    if strangers:
        parser.error(f"--config-json names steps {', '.join(strangers)} that the groups {', '.join(args.groups)} do not run")
    own = {g: {k: v for k, v in ops.items() if k in job.graph.node_dict} for g, job in jobs.items()}
    for group, job in jobs.items():  # every group's config checked before the first run, not minutes into the second
        try:
            dg.validate_run_config(job, {"ops": own[group]})
        except dg.DagsterInvalidConfigError as e:  # Dagster's message lists every error over many lines
            parser.error(f"--config-json for {group}: " + "; ".join(err.message.replace("\n", " ") for err in e.errors))
    try:
        dagster_home()  # without the Makefile: the instance under $TRAFFICLEARN_HOME, as `make demo` has it
    except InstanceError as e:
        parser.error(str(e))
    with dg.DagsterInstance.get() as instance:
        for group, job in jobs.items():
            ok, line = run(job, group, instance, own[group])
            print(line, flush=True)
            if not ok:
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
