"""Shared code of the benchmarks: the scaled data set, the timed pipeline chain, result recording.

Not a test module (pytest only collects test_*.py); the benchmarks import it as `benchlib` because
pytest puts tests/bench on sys.path (rootdir-relative "prepend" import mode).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import polars as pl

REPO = Path(__file__).resolve().parents[2]
OPENSKY = REPO / "data" / "opensky" / "kaliningrad_2022-02-22_2022-03-05.parquet"
N_REAL_FLIGHTS = 93

# Knobs (environment variables) so that a quick run is possible; the defaults are the targets.
SCALED_FLIGHTS = int(os.environ.get("TRAFFICLEARN_BENCH_FLIGHTS", "10000"))
# keep every STEP_S-th second of the raw 1 s state vectors before replicating (memory: see README)
STEP_S = int(os.environ.get("TRAFFICLEARN_BENCH_STEP_S", "5"))
TRAFFIC_SUBSET_FLIGHTS = int(os.environ.get("TRAFFICLEARN_BENCH_TRAFFIC_FLIGHTS", "500"))
# traffic gets as many worker processes as we have cores (polars uses them all too)
TRAFFIC_WORKERS = int(os.environ.get("TRAFFICLEARN_BENCH_TRAFFIC_WORKERS", "0")) or len(os.sched_getaffinity(0))
DTW_SERIES = int(os.environ.get("TRAFFICLEARN_BENCH_DTW_SERIES", "1000"))

TARGET_10K_S = 60.0
TARGET_TRAFFIC_RATIO = 20.0
REAL_REPEAT = 5  # the 93 real flights: both sides' best of 5 after a warm-up (single runs of either vary by ±15 %)
TARGET_DTW_S = 60.0


def fmt_s(s: float) -> str:
    return f"{s:.1f} s" if s >= 10 else f"{s:.2f} s"


def machine() -> dict:
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {
        "cpus": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "polars_threads": pl.thread_pool_size(),
        "python": platform.python_version(),
        "polars": pl.__version__,
        "numpy": np.__version__,
        "loadavg_1_5_15": [round(x, 2) for x in load],
    }


def warn_if_busy(label: str) -> float:
    """Load average of the last minute; says so when other work competes for the cores."""
    load = os.getloadavg()[0]
    cores = os.cpu_count() or 1
    if load > 0.5 * cores:
        print(f"\nWARN {label}: load average {load:.1f} on {cores} cores before timing: other processes compete, timings are pessimistic")
    return load


# --------------------------------------------------------------------------------------------- data


def scaled_state_vectors(raw: pl.DataFrame, n_copies: int, step_s: int = STEP_S, seed: int = 0) -> pl.DataFrame:
    """n_copies perturbed copies of the real OpenSky state vectors, in the same schema, sorted by time.

    Copy k: time (and lastposupdate) shifted by k days; every aircraft gets its own icao24 and every
    callsign its own number (airline prefix kept, so routes stay recognisable); each (copy, aircraft)
    is offset by N(0, 0.01°) in lat/lon and N(0, 15 m) in altitude, and every row gets N(0, 1e-4°)
    position and N(0, 3 m) altitude noise. With step_s > 1 only rows whose time is a multiple of
    step_s seconds are kept (before replicating). Built with vectorised polars joins, no Python loop
    over rows.
    """
    base = raw.filter(pl.col("time").dt.epoch("s") % step_s == 0) if step_s > 1 else raw
    rng = np.random.default_rng(seed)
    icaos = sorted(base["icao24"].unique().to_list())
    calls = sorted(base["callsign"].drop_nulls().unique().to_list())
    ki = np.repeat(np.arange(n_copies), len(icaos))
    icao_map = pl.DataFrame(
        {
            "_k": ki,
            "icao24": icaos * n_copies,
            "_icao24": [f"{0x100000 + i:06x}" for i in range(len(ki))],
            "_dlat": rng.normal(0.0, 0.01, len(ki)),
            "_dlon": rng.normal(0.0, 0.01, len(ki)),
            "_dalt": rng.normal(0.0, 15.0, len(ki)),
        }
    )
    kc = np.repeat(np.arange(n_copies), len(calls))
    call_map = pl.DataFrame(
        {
            "_k": kc,
            "callsign": calls * n_copies,
            "_callsign": [f"{c.strip()[:3]}{i:04d}" for i, c in enumerate(calls * n_copies)],
        }
    )
    out = (
        base.join(pl.DataFrame({"_k": np.arange(n_copies)}), how="cross")
        .join(icao_map, on=["_k", "icao24"], how="left")
        .join(call_map, on=["_k", "callsign"], how="left")
    )
    n = out.height
    noise = lambda sd: pl.Series(rng.normal(0.0, sd, n))  # noqa: E731
    return (
        out.with_columns(
            time=pl.col("time") + pl.duration(days=pl.col("_k")),
            lastposupdate=pl.col("lastposupdate") + pl.col("_k").cast(pl.Float64) * 86400.0,
            icao24=pl.col("_icao24"),
            callsign=pl.col("_callsign"),
            lat=pl.col("lat") + pl.col("_dlat") + noise(1e-4),
            lon=pl.col("lon") + pl.col("_dlon") + noise(1e-4),
            baroaltitude=pl.col("baroaltitude") + pl.col("_dalt") + noise(3.0),
        )
        .select(raw.columns)
        .sort("time")
    )


def write_scaled(path: Path, n_flights: int, step_s: int = STEP_S, seed: int = 0) -> dict:
    """Write >= n_flights scaled flights to `path`; returns what was built (not timed as pipeline work)."""
    raw = pl.read_parquet(OPENSKY)
    n_copies = -(-n_flights // N_REAL_FLIGHTS)
    t = time.perf_counter()
    df = scaled_state_vectors(raw, n_copies, step_s, seed)
    df.write_parquet(path)
    info = {
        "path": str(path),
        "copies": n_copies,
        "step_s": step_s,
        "rows": df.height,
        "source_flights": n_copies * N_REAL_FLIGHTS,
        "file_mb": round(path.stat().st_size / 1e6, 1),
        "build_s": round(time.perf_counter() - t, 2),
    }
    del df, raw
    return info


# --------------------------------------------------------------------------------------------- our chain


@dataclass
class ChainRun:
    seconds: dict[str, float] = field(default_factory=dict)
    cpu_s: float = 0.0  # CPU time of this process (all threads): less sensitive than wall time to other load
    rows_read: int = 0
    rows_kept: int = 0
    flights: int = 0
    grid_rows: int = 0
    phases: pl.DataFrame | None = None
    flights_table: pl.DataFrame | None = None

    @property
    def total(self) -> float:
        return sum(self.seconds.values())


def run_chain(path: Path, keep: bool = False) -> ChainRun:
    """raw file -> ingest (read, normalise, clean, split) -> flights (origin/destination/route)
    -> 20 s grid -> phases, exactly the functions the Dagster assets call (weather sampling excluded)."""
    from models.aviation.airports import flights_table
    from models.aviation.ingest import IngestConfig, ingest
    from models.aviation.phases import PhaseConfig, assign_phases
    from models.aviation.resample import resample

    run = ChainRun()
    c0 = time.process_time()
    t0 = time.perf_counter()
    tracks, rejects, summary = ingest(path, IngestConfig())
    t1 = time.perf_counter()
    flights = flights_table(tracks)
    t2 = time.perf_counter()
    grid = resample(tracks, dt_s=20.0)
    t3 = time.perf_counter()
    phased = assign_phases(grid, flights, PhaseConfig())
    t4 = time.perf_counter()
    run.cpu_s = time.process_time() - c0
    run.seconds = {"ingest": t1 - t0, "flights_table": t2 - t1, "resample_20s": t3 - t2, "phases": t4 - t3}
    run.rows_read = int(summary.filter(pl.col("outcome") == "read")["rows"].sum())
    run.rows_kept = tracks.height
    run.flights = flights.height
    run.grid_rows = phased.height
    assert phased["phase"].null_count() == 0
    if keep:
        run.phases, run.flights_table = phased, flights
    return run


def chain_record(run: ChainRun) -> dict:
    return {
        "total_s": round(run.total, 3),
        "cpu_s": round(run.cpu_s, 3),
        "stages_s": {k: round(v, 3) for k, v in run.seconds.items()},
        "rows_read": run.rows_read,
        "rows_kept": run.rows_kept,
        "flights": run.flights,
        "grid_rows_20s": run.grid_rows,
    }


# --------------------------------------------------------------------------------------------- traffic


def traffic_python() -> tuple[str | None, str]:
    """(python executable that can import traffic 2.13, how it was found) or (None, why not)."""
    explicit = os.environ.get("TRAFFICLEARN_BENCH_TRAFFIC_PYTHON")
    candidates = [explicit] if explicit else [str(REPO / ".venv-bench" / "bin" / "python"), sys.executable]
    why = []
    for exe in candidates:
        if not exe or not Path(exe).exists():
            why.append(f"{exe}: not found")
            continue
        probe = subprocess.run(
            [exe, str(Path(__file__).with_name("traffic_runner.py")), "--probe"],
            capture_output=True, text=True, timeout=300, env=traffic_env(),
        )
        if probe.returncode == 0:
            return exe, probe.stdout.strip()
        last = (probe.stderr.strip().splitlines() or ["?"])[-1]
        why.append(f"{exe}: {last}")
    return None, "; ".join(why)


def traffic_env() -> dict:
    """Offline and side-effect free: traffic's config and cache go to a throw-away folder, no progress bars."""
    import tempfile

    scratch = Path(tempfile.gettempdir()) / "trafficlearn-bench-traffic"
    env = dict(os.environ)
    env.update(
        XDG_CONFIG_HOME=str(scratch / "config"),
        TRAFFIC_CACHE_PATH=str(scratch / "cache"),
        TRAFFIC_TQDM_STYLE="silent",
        PYTHONWARNINGS="ignore",
    )
    return env


def run_traffic(exe: str, path: Path, repeat: int = 1, workers: int = TRAFFIC_WORKERS, timeout: int = 900) -> dict:
    """Run tests/bench/traffic_runner.py on `path` in `exe`; returns its JSON (timings measured inside)."""
    proc = subprocess.run(
        [exe, str(Path(__file__).with_name("traffic_runner.py")), str(path), "--repeat", str(repeat), "--workers", str(workers)],
        capture_output=True, text=True, timeout=timeout, env=traffic_env(), cwd=Path(path).parent,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"traffic runner failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------------------------- results


def results_dir(home: str) -> Path:
    return Path(home) / "bench"


def save_results(home: str, results: dict) -> Path:
    out = results_dir(home)
    out.mkdir(parents=True, exist_ok=True)
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    doc = {"created_utc": stamp, "machine": machine(), "results": results}
    path = out / f"bench-{stamp}.json"
    path.write_text(json.dumps(doc, indent=2, default=str))
    (out / "latest.json").write_text(json.dumps(doc, indent=2, default=str))
    return path
