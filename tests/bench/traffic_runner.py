"""The `traffic` (2.13) side of the ours-vs-traffic benchmark, run as a subprocess by test_bench_traffic.py.

    python traffic_runner.py FILE.parquet [--repeat N] [--workers W]   -> one JSON line on stdout
    python traffic_runner.py --probe                                    -> exit 0 if traffic imports

It runs in whichever interpreter has traffic installed (the project venv, or a separate one, see
benchlib.traffic_python), so it imports nothing from trafficlearn. The caller sets XDG_CONFIG_HOME and
TRAFFIC_CACHE_PATH to a scratch folder: traffic then writes its config there and needs no network
(nothing here downloads: no OpenSky query, no aircraft database, no airport/navaid data).

The chain, timed from reading the file to the evaluated result (the import of traffic is timed apart):
  1. read the OpenSky state vectors (pyarrow -> pandas, numpy dtypes, as traffic's own loaders give)
  2. rename to traffic's columns and units (ft, kt, ft/min, last_position as a timestamp)
  3. Traffic(df), drop on-ground rows and rows without position/altitude (our ingest drops them too)
  4. lazily per flight: split each (icao24, callsign) on gaps > 30 min and assign_id (our gap_split_s),
     resample("20s") (traffic drops OpenSky's repeated positions via last_position, then interpolates),
     phases() (openap's FlightPhase fuzzy logic, twindow=60)
  5. eval(max_workers=W)
Not done on the traffic side (it would only make traffic slower): spike filtering (Flight.filter()),
origin/destination inference.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

FT = 0.3048
KT = 1852.0 / 3600.0


def probe() -> None:
    from importlib.metadata import version

    import pandas as pd
    from traffic.core import Traffic  # noqa: F401  (the import that fails with pandas 3)

    print(f"traffic {version('traffic')}, pandas {pd.__version__}, openap {version('openap')}")


def to_traffic_frame(path: str):
    import numpy as np
    import pandas as pd
    import pyarrow.parquet as pq

    df = pq.read_table(path).to_pandas(ignore_metadata=True)
    f = lambda c: df[c].to_numpy(dtype=float, na_value=np.nan)  # noqa: E731
    return pd.DataFrame(
        {
            "timestamp": df["time"],
            "icao24": df["icao24"],
            "callsign": df["callsign"].str.strip(),
            "latitude": f("lat"),
            "longitude": f("lon"),
            "altitude": f("baroaltitude") / FT,
            "groundspeed": f("velocity") / KT,
            "track": f("heading"),
            "vertical_rate": f("vertrate") / FT * 60.0,
            "onground": df["onground"].fillna(False).astype(bool),
            "last_position": pd.to_datetime(f("lastposupdate"), unit="s", utc=True),
        }
    )


def chain(frame, workers: int):
    from traffic.core import Traffic

    t = Traffic(frame).query("not onground and latitude.notnull() and longitude.notnull() and altitude.notnull()")
    return (
        t.iterate_lazy(iterate_kw=dict(by="30 min"))
        .assign_id()
        .resample("20s")
        .phases()
        .eval(max_workers=workers)
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("path", nargs="?")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--probe", action="store_true")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.probe:
        probe()
        return

    t = time.perf_counter()
    from importlib.metadata import version

    import pandas as pd
    from traffic.core import Traffic  # noqa: F401

    import_s = time.perf_counter() - t

    # warm-up (untimed): one flight through the whole chain, so that lazy imports (openap) are done
    t = time.perf_counter()
    frame = to_traffic_frame(args.path)
    first = frame[(frame.icao24 == frame.icao24.iloc[0]) & (frame.callsign == frame.callsign.iloc[0])]
    chain(first, 1)
    warmup_s = time.perf_counter() - t
    del frame, first

    runs = []
    out = None
    for _ in range(args.repeat):
        out = None
        t0 = time.perf_counter()
        frame = to_traffic_frame(args.path)
        t1 = time.perf_counter()
        out = chain(frame, args.workers)
        t2 = time.perf_counter()
        runs.append({"read_convert_s": round(t1 - t0, 3), "traffic_chain_s": round(t2 - t1, 3), "total_s": round(t2 - t0, 3)})
        del frame
    phases = out.data["phase"].value_counts().to_dict() if out is not None else {}
    print(
        json.dumps(
            {
                "traffic": version("traffic"),
                "pandas": pd.__version__,
                "openap": version("openap"),
                "python": sys.version.split()[0],
                "workers": args.workers,
                "import_s": round(import_s, 3),
                "warmup_s": round(warmup_s, 3),
                "runs": runs,
                "best_total_s": min(r["total_s"] for r in runs),
                "flights": len(out) if out is not None else 0,
                "grid_rows_20s": len(out.data) if out is not None else 0,
                "phase_rows": {str(k): int(v) for k, v in phases.items()},
            }
        )
    )


if __name__ == "__main__":
    main()
