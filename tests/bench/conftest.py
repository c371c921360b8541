"""Benchmarks (`make bench`): fixtures shared by tests/bench/test_bench_*.py and the results file.

Results go to $TRAFFICLEARN_HOME/bench/latest.json (and a time-stamped copy). TRAFFICLEARN_HOME is read
here, at import, because tests/conftest.py points it at a per-test temporary folder while tests run.

The benchmarks take minutes, so they only run when asked for: `pytest tests/bench` (a path inside
tests/bench on the command line) or TRAFFICLEARN_BENCH=1. A plain `pytest` skips them.
"""

import os
import time
from pathlib import Path

import pytest

import benchlib as b

# the process is set up as the pipeline's are (allocators: models/memory.py) by tests/conftest.py, loaded first
HOME_AT_START = str(Path(os.environ.get("TRAFFICLEARN_HOME", "var")).resolve())
RESULTS: dict = {}
BENCH_DIR = Path(__file__).resolve().parent


def _asked_for(config) -> bool:
    if os.environ.get("TRAFFICLEARN_BENCH") == "1":
        return True
    for arg in config.args:
        p = Path(arg.split("::")[0]).resolve()
        if p == BENCH_DIR or BENCH_DIR in p.parents:
            return True
    return False


def pytest_configure(config):
    # a failed target is one line; the default long traceback would print the fixtures' big reprs
    if _asked_for(config) and config.option.tbstyle == "auto":
        config.option.tbstyle = "short"


def pytest_collection_modifyitems(config, items):
    if _asked_for(config):
        return
    skip = pytest.mark.skip(reason="benchmark: run with `make bench` or `pytest tests/bench`")
    for item in items:
        if BENCH_DIR in Path(str(item.fspath)).resolve().parents:
            item.add_marker(skip)


def pytest_sessionfinish(session, exitstatus):
    if not RESULTS:
        return
    path = b.save_results(HOME_AT_START, RESULTS)
    tr = session.config.pluginmanager.get_plugin("terminalreporter")
    line = f"BENCH results written to {path} (and {path.parent / 'latest.json'})"
    if tr is not None:
        tr.write_line(line)
    else:
        print(line)


@pytest.fixture(scope="session")
def bench_results() -> dict:
    return RESULTS


@pytest.fixture(scope="session")
def real_baseline(bench_results) -> b.ChainRun:
    """Our chain on the 93 real flights (528,432 rows at 1 s): one warm-up run, then the best of b.REAL_REPEAT (5)."""
    b.run_chain(b.OPENSKY)  # warm-up: imports, openap airport table, polars thread pool
    load = b.warn_if_busy("raw->phases 93 real flights")
    runs = [b.run_chain(b.OPENSKY) for _ in range(b.REAL_REPEAT)]
    best = min(runs, key=lambda r: r.total)
    bench_results["ours_real_93"] = {
        **b.chain_record(best),
        "runs_total_s": [round(r.total, 3) for r in runs],
        "measure": f"best of {b.REAL_REPEAT} after one warm-up run",
        "loadavg_before": round(load, 2),
        "input": f"{b.OPENSKY.relative_to(b.REPO)} (1 s OpenSky state vectors)",
    }
    print(
        f"\nBENCH raw->phases {best.flights} real flights ({best.rows_read:,} rows at 1 s): {b.fmt_s(best.total)} "
        f"(best of {b.REAL_REPEAT}; CPU {b.fmt_s(best.cpu_s)}; ingest {b.fmt_s(best.seconds['ingest'])}, flights {b.fmt_s(best.seconds['flights_table'])}, "
        f"20 s grid {b.fmt_s(best.seconds['resample_20s'])}, phases {b.fmt_s(best.seconds['phases'])}; "
        f"{1000 * best.total / best.flights:.1f} ms/flight)"
    )
    return best


@pytest.fixture(scope="session")
def scaled_10k(tmp_path_factory, bench_results):
    """>= 10,000 flights of perturbed, time-shifted copies of the real data, written to Parquet (untimed)."""
    path = tmp_path_factory.mktemp("bench") / f"scaled_{b.SCALED_FLIGHTS}_flights.parquet"
    t = time.perf_counter()
    info = b.write_scaled(path, b.SCALED_FLIGHTS, b.STEP_S)
    print(
        f"\nBENCH built scaled set: {info['copies']} copies x 93 flights = {info['source_flights']:,} flights, "
        f"{info['rows']:,} rows (every {info['step_s']} s of the raw 1 s rows), {info['file_mb']} MB Parquet "
        f"in {time.perf_counter() - t:.1f} s (not timed as pipeline work)"
    )
    bench_results["scaled_set"] = info
    yield info
    path.unlink(missing_ok=True)  # 370 MB; pytest keeps its last three temporary folders
