"""A Dagster logger that shows a run as a progress bar on the terminal (used by `python -m pipelines.materialize`).

It is only active when a run's config names it (`loggers: {progress: {config: ...}}`); runs from the UI
or `dagster asset materialize` keep Dagster's console logger. On a terminal it draws one tqdm bar per run
(steps done / steps in the job, the step running now, the latest message the step logged); elsewhere (CI,
a pipe) it prints one line per finished step. Warnings and errors are always printed. Every record also
goes to a plain-text log file, and the full event log stays in the Dagster instance (the UI).
"""

import logging
import sys
import time
from pathlib import Path

import dagster as dg
from dagster._core.events import RunFailureReason
from dagster._core.log_manager import get_log_record_metadata, has_log_record_metadata
from tqdm import tqdm


class ProgressHandler(logging.Handler):
    """One run's records: a tqdm bar (or a line per finished step off a terminal), warnings and failed checks
    printed, every record appended to `log_file`."""

    def __init__(self, total: int, desc: str, log_file: Path, stream=None):
        super().__init__(logging.DEBUG)
        self.stream = stream or sys.stderr
        self.desc, self.total, self.done = desc, total, 0
        self._bar: tqdm | None = None
        self.tty = self.stream.isatty()  # asked now: while a step runs, Dagster redirects stderr to capture it
        self.started: dict[str, float] = {}
        self.log_file = log_file
        log_file.parent.mkdir(parents=True, exist_ok=True)

    def emit(self, record: logging.LogRecord) -> None:
        meta = get_log_record_metadata(record) if has_log_record_metadata(record) else {}
        event = meta.get("dagster_event")
        kind = event.event_type_value if event is not None else None
        step = meta.get("step_key") or ""
        message = meta.get("orig_message") or record.getMessage()
        error = event.step_failure_data.error if kind == "STEP_FAILURE" else None
        check = event.asset_check_evaluation_data if kind == "ASSET_CHECK_EVALUATION" else None
        # what a failed check measured: Dagster's message only says that it did not pass
        facts = ", ".join(f"{k}={v.value}" for k, v in check.metadata.items()) if check and not check.passed else ""
        with self.log_file.open("a", encoding="utf-8") as log:  # a few hundred records a run: reopening is cheap
            log.write(f"{time.strftime('%H:%M:%S')} {record.levelname:7} {step or '-'} {kind or ''} {message}{' ' + facts if facts else ''}\n")
            if error is not None:
                log.write(error.to_string())
        if error is not None:  # the user's exception, not Dagster's wrapper around it
            while error.cause is not None:
                error = error.cause
            message = f"{message} {error.message.strip()} (traceback in {self.log_file})"
        if kind == "STEP_START":
            self.started[step] = time.perf_counter()
            self.bar.set_description(f"{self.desc}: {step}", refresh=False)
            self.bar.set_postfix_str("", refresh=True)
        elif kind in ("STEP_SUCCESS", "STEP_FAILURE", "STEP_SKIPPED"):
            self.done += 1
            self.bar.update(1)
            if self.bar.disable:
                took = time.perf_counter() - self.started.get(step, time.perf_counter())
                outcome = {"STEP_SUCCESS": "done", "STEP_FAILURE": "FAILED", "STEP_SKIPPED": "skipped"}[kind]
                self._print(f"[{self.desc} {self.done}/{self.total}] {step} {outcome} in {took:.1f} s")
        elif kind is None and record.levelno == logging.INFO:
            self.bar.set_postfix_str(message.splitlines()[0][:80] if message else "")
        # a step skipped after a failure upstream is one "skipped" in the count, not an error line per step; the run's
        # "Steps failed: [...]" only repeats the failed step's line (the caller prints the run's outcome)
        repeats = kind == "PIPELINE_FAILURE" and event.job_failure_data.failure_reason == RunFailureReason.STEP_FAILURE
        if record.levelno >= logging.WARNING and not message.endswith("Not executing.") and not repeats:
            self._print(f"{record.levelname} {step}: {message}")
        elif check is not None and not check.passed:
            # Dagster logs a failed check at DEBUG and its step still succeeds: say so, or the terminal shows only "done"
            shown = f": {facts[:300]}" if facts else ""
            if len(facts) > 300:
                shown += f"… (whole in {self.log_file})"
            self._print(f"{check.severity.value} {step}: check {check.check_name} on {check.asset_key.to_user_string()} did not pass{shown}")
        if kind in ("PIPELINE_SUCCESS", "PIPELINE_FAILURE"):  # the run ended (these are the run events' values)
            self.bar.close()

    @property
    def bar(self) -> tqdm:
        # made on first use: Dagster may build a run's loggers more than once, and an idle bar would push
        # the live one a line down
        if self._bar is None:
            self._bar = tqdm(
                total=self.total, desc=self.desc, unit="step", file=self.stream, dynamic_ncols=True,
                disable=not self.tty,
            )
        return self._bar

    def _print(self, line: str) -> None:
        tqdm.write(line, file=self.stream) if not self.bar.disable else print(line, file=self.stream, flush=True)


@dg.logger(
    config_schema={"total_steps": int, "desc": str, "log_file": str},
    description="Progress bar on the terminal, full text log to a file (pipelines.materialize).",
)
def progress_logger(init_context: dg.InitLoggerContext) -> logging.Logger:
    cfg = init_context.logger_config
    log = logging.Logger(f"trafficlearn.progress.{init_context.run_id}", level=logging.DEBUG)
    log.addHandler(ProgressHandler(cfg["total_steps"], cfg["desc"], Path(cfg["log_file"])))
    return log
