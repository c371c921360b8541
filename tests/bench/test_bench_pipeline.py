"""raw -> cleaned -> 20 s -> phases, on the 93 real flights and on >= 10,000 scaled flights.

Target (issue): 10,000 flights raw -> phases in under 60 s on 2 cores. The chain is timed from reading
the Parquet file to the phase column (ingest, flights table with origin/destination/route, 20 s grid,
phases), i.e. the work of flight_ingest + tracks_20s without weather sampling and without Dagster.
"""

from pathlib import Path

import benchlib as b


def test_raw_to_phases_real_flights(real_baseline):
    assert real_baseline.flights == b.N_REAL_FLIGHTS
    assert real_baseline.rows_read == 528_432


def test_raw_to_phases_10k_flights(scaled_10k, real_baseline, bench_results):
    load = b.warn_if_busy(f"raw->phases {b.SCALED_FLIGHTS:,} flights")
    run = b.run_chain(Path(scaled_10k["path"]))
    base_per_flight = real_baseline.total / real_baseline.flights
    per_flight = run.total / run.flights
    bench_results["ours_scaled"] = {
        **b.chain_record(run),
        "measure": "one run",
        "loadavg_before": round(load, 2),
        "input": f"scaled set: {scaled_10k['copies']} perturbed copies, every {scaled_10k['step_s']} s of the raw rows",
        "target_s": b.TARGET_10K_S,
        "share_of_target": round(run.total / b.TARGET_10K_S, 3),
        "ms_per_flight": round(1000 * per_flight, 3),
        "ms_per_flight_real_93": round(1000 * base_per_flight, 3),
    }
    print(
        f"\nBENCH raw->phases {run.flights:,} flights ({run.rows_read:,} rows): {b.fmt_s(run.total)} "
        f"(target < {b.TARGET_10K_S:.0f} s, {run.total / b.TARGET_10K_S:.2f}x the budget; CPU {b.fmt_s(run.cpu_s)}; "
        f"ingest {b.fmt_s(run.seconds['ingest'])}, flights {b.fmt_s(run.seconds['flights_table'])}, "
        f"20 s grid {b.fmt_s(run.seconds['resample_20s'])}, phases {b.fmt_s(run.seconds['phases'])}; "
        f"{run.grid_rows:,} grid rows; {1000 * per_flight:.1f} ms/flight vs {1000 * base_per_flight:.1f} ms/flight "
        f"on the 93 real flights at 1 s)"
    )
    assert run.flights >= b.SCALED_FLIGHTS, f"scaled set should give >= {b.SCALED_FLIGHTS} flights, got {run.flights}"
    assert run.total < b.TARGET_10K_S, (
        f"raw->phases on {run.flights:,} flights took {run.total:.1f} s, target < {b.TARGET_10K_S:.0f} s "
        f"(stages: {bench_results['ours_scaled']['stages_s']})"
    )
