"""Ours vs the `traffic` library (2.13) on the same input, in the same run. Target: >= 20x faster.

Both sides read the same Parquet file of OpenSky state vectors and end with every flight on a 20 s grid
with a phase per point; what each side does is in benchlib.run_chain and traffic_runner.py (traffic
does less: no spike filter, no origin/destination). traffic runs in a subprocess (its own interpreter,
see benchlib.traffic_python) with max_workers = the usable cores; its import (~4-6 s) is not counted,
and both sides get a warm-up first. Ratio = traffic's time / ours on the identical file.

Compared:
  * the 93 real flights (528,432 rows at 1 s): each side's best of 5 (benchlib.REAL_REPEAT);
  * a scaled subset of >= TRAFFICLEARN_BENCH_TRAFFIC_FLIGHTS (500) flights, built like the 10,000-flight
    set (perturbed copies, every 5th second): ours best of 2, traffic one run.
"""

import os

import pytest

import benchlib as b

WORKERS = b.TRAFFIC_WORKERS


@pytest.fixture(scope="session")
def traffic_exe(bench_results) -> str:
    exe, info = b.traffic_python()
    if exe is None:
        msg = (
            f"traffic 2.13 is not importable ({info}). traffic 2.13 needs pandas < 3; "
            "make bench installs it into .venv-bench, or set TRAFFICLEARN_BENCH_TRAFFIC_PYTHON"
        )
        if os.environ.get("TRAFFICLEARN_BENCH_TRAFFIC_PYTHON"):
            pytest.fail(msg)
        pytest.skip(msg)
    bench_results["traffic_interpreter"] = {"python": exe, "versions": info}
    print(f"\nBENCH traffic side runs in {exe}: {info}, max_workers={WORKERS}")
    return exe


def _compare(label: str, ours_s: float, ours_flights: int, tr: dict, bench_results: dict, key: str, extra: dict, load: float):
    ratio = tr["best_total_s"] / ours_s
    bench_results[key] = {
        "input": label,
        "ours_s": round(ours_s, 3),
        "traffic_s": tr["best_total_s"],
        "ratio": round(ratio, 2),
        "target_ratio": b.TARGET_TRAFFIC_RATIO,
        "ours_ms_per_flight": round(1000 * ours_s / ours_flights, 3),
        "traffic_ms_per_flight": round(1000 * tr["best_total_s"] / max(tr["flights"], 1), 3),
        "ours_flights": ours_flights,
        "traffic": tr,
        "loadavg_before": round(load, 2),
        **extra,
    }
    print(
        f"\nBENCH ours vs traffic on {label}: ours {b.fmt_s(ours_s)}, traffic {b.fmt_s(tr['best_total_s'])}, "
        f"ratio {ratio:.1f}x (target >= {b.TARGET_TRAFFIC_RATIO:.0f}x); flights ours {ours_flights} / traffic "
        f"{tr['flights']}, 20 s points ours {extra.get('ours_grid_rows', 0):,} / traffic {tr['grid_rows_20s']:,}; "
        f"traffic {1000 * tr['best_total_s'] / max(tr['flights'], 1):.0f} ms/flight, ours {1000 * ours_s / ours_flights:.1f} ms/flight"
    )
    return ratio


def test_ours_vs_traffic_real_flights(traffic_exe, real_baseline, bench_results):
    load = b.warn_if_busy("traffic on 93 real flights")
    tr = b.run_traffic(traffic_exe, b.OPENSKY, repeat=b.REAL_REPEAT, workers=WORKERS)
    ratio = _compare(
        f"the {real_baseline.flights} real flights ({real_baseline.rows_read:,} rows at 1 s)",
        real_baseline.total, real_baseline.flights, tr, bench_results, "ours_vs_traffic_real_93",
        {"ours_grid_rows": real_baseline.grid_rows, "measure": f"each side's best of {b.REAL_REPEAT} after a warm-up"}, load,
    )
    assert tr["flights"] == real_baseline.flights, "both sides should find the same flights"
    assert ratio >= b.TARGET_TRAFFIC_RATIO, f"ours is {ratio:.1f}x faster than traffic on the real flights, target >= 20x"


def test_ours_vs_traffic_scaled_subset(traffic_exe, tmp_path_factory, bench_results):
    path = tmp_path_factory.mktemp("bench_traffic") / "scaled_subset.parquet"
    info = b.write_scaled(path, b.TRAFFIC_SUBSET_FLIGHTS, b.STEP_S, seed=1)
    load = b.warn_if_busy(f"ours vs traffic on {info['source_flights']} scaled flights")
    ours = min((b.run_chain(path) for _ in range(2)), key=lambda r: r.total)
    tr = b.run_traffic(traffic_exe, path, repeat=1, workers=WORKERS)
    ratio = _compare(
        f"{ours.flights} scaled flights ({info['rows']:,} rows, every {info['step_s']} s)",
        ours.total, ours.flights, tr, bench_results, "ours_vs_traffic_scaled_subset",
        {"ours_grid_rows": ours.grid_rows, "scaled_subset": info, "measure": "ours best of 2, traffic one run, after warm-ups"}, load,
    )
    scaled = bench_results.get("ours_scaled")
    if scaled:  # per-flight throughput of ours at 10,000 flights against traffic's on this subset (information only)
        at_scale = tr["best_total_s"] / max(tr["flights"], 1) / (scaled["ms_per_flight"] / 1000)
        bench_results["ours_vs_traffic_scaled_subset"]["ratio_per_flight_vs_ours_at_scale"] = round(at_scale, 2)
        print(
            f"BENCH per-flight throughput: traffic on this subset vs ours on {scaled['flights']:,} flights: "
            f"{at_scale:.1f}x (information only)"
        )
    assert tr["flights"] == ours.flights, "both sides should find the same flights"
    assert ratio >= b.TARGET_TRAFFIC_RATIO, f"ours is {ratio:.1f}x faster than traffic on the scaled subset, target >= 20x"
