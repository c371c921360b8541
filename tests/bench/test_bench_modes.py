"""DTW clustering of 1,000 cruise sub-trajectories in under 60 s (models.aviation.modes.cluster_series).

The sub-trajectories are real: the cruise phase of the first 1,000 flights of route UUEE-UMKK from a
scaled set (perturbed, time-shifted copies of the real flights, built like the 10,000-flight set) run
through our own chain (ingest -> 20 s grid -> phases). As in trajectory_modes: (lon, lat, alt_m),
min-max scaled over all points of the set, then cluster_series (normalised DTW matrix, Ward linkage,
silhouette over k = 2..8). Only cluster_series is timed. Baseline in the same run: the same call on
the first 100 of the series, whose pair count is ~1/100 of the 1,000's.
"""

import time

import numpy as np
import polars as pl
import pytest

import benchlib as b

ROUTE = "UUEE-UMKK"  # 57 of the 93 real flights


@pytest.fixture(scope="module")
def cruise_series(tmp_path_factory, bench_results):
    n = b.DTW_SERIES
    path = tmp_path_factory.mktemp("bench_modes") / "scaled_for_dtw.parquet"
    info = b.write_scaled(path, (n // 57 + 2) * b.N_REAL_FLIGHTS, b.STEP_S, seed=2)
    run = b.run_chain(path, keep=True)
    route_ids = run.flights_table.filter(pl.col("route") == ROUTE)["flight_id"]
    pts = (
        run.phases.filter((pl.col("phase") == "cruise") & pl.col("flight_id").is_in(route_ids.implode()))
        .drop_nulls(["lon", "lat", "alt_m"])
        .sort("flight_id", "ts")
        .filter(pl.len().over("flight_id") >= 2)
    )
    keep = pts["flight_id"].unique(maintain_order=True).head(n)
    pts = pts.filter(pl.col("flight_id").is_in(keep.implode()))
    lens = pts.group_by("flight_id", maintain_order=True).len()["len"].to_numpy()
    x = pts.select("lon", "lat", "alt_m").to_numpy().astype(np.float64)
    lo, span = x.min(axis=0), np.ptp(x, axis=0)
    x = np.ascontiguousarray((x - lo) / np.where(span > 0, span, 1.0))
    series = np.split(x, np.cumsum(lens)[:-1])
    bench_results["dtw_input"] = {
        "scaled_set": info,
        "route": ROUTE,
        "series": len(series),
        "points_per_series": {"mean": round(float(lens.mean()), 1), "min": int(lens.min()), "max": int(lens.max())},
    }
    return series


def test_dtw_clustering_1000_subtrajectories(cruise_series, bench_results):
    modes = pytest.importorskip("models.aviation.modes", reason="models/aviation/modes.py does not exist yet")
    if not hasattr(modes, "cluster_series"):
        pytest.skip("models.aviation.modes has no cluster_series yet")
    series = cruise_series
    n = len(series)
    assert n >= b.DTW_SERIES, f"only {n} cruise sub-trajectories on {ROUTE}, wanted {b.DTW_SERIES}"
    lens = np.array([len(s) for s in series])

    small = series[:100]
    t = time.perf_counter()
    modes.cluster_series(small, max_modes=8)
    base_s = time.perf_counter() - t

    load = b.warn_if_busy(f"DTW clustering of {n} series")
    t = time.perf_counter()
    c = modes.cluster_series(series, max_modes=8)
    took = time.perf_counter() - t

    pairs, base_pairs = n * (n - 1) // 2, len(small) * (len(small) - 1) // 2
    bench_results["dtw_clustering"] = {
        "series": n,
        "pairs": pairs,
        "mean_points": round(float(lens.mean()), 1),
        "seconds": round(took, 3),
        "target_s": b.TARGET_DTW_S,
        "share_of_target": round(took / b.TARGET_DTW_S, 3),
        "n_modes": int(c.n_modes),
        "silhouette": c.silhouette,
        "baseline_100_series_s": round(base_s, 3),
        "ratio_vs_baseline": round(took / base_s, 1) if base_s > 0 else None,
        "pairs_ratio_vs_baseline": round(pairs / base_pairs, 1),
        "measure": "one run of modes.cluster_series(series, max_modes=8)",
        "loadavg_before": round(load, 2),
    }
    print(
        f"\nBENCH DTW clustering of {n:,} cruise sub-trajectories ({ROUTE}, mean {lens.mean():.0f} points, "
        f"{pairs:,} pairs): {b.fmt_s(took)} (target < {b.TARGET_DTW_S:.0f} s, {took / b.TARGET_DTW_S:.2f}x the budget); "
        f"{c.n_modes} modes, silhouette {c.silhouette if c.silhouette is None else round(c.silhouette, 3)}; "
        f"baseline 100 series {b.fmt_s(base_s)}, ratio {took / max(base_s, 1e-9):.0f}x for {pairs / base_pairs:.0f}x the pairs"
    )
    assert took < b.TARGET_DTW_S, f"DTW clustering of {n} sub-trajectories took {took:.1f} s, target < {b.TARGET_DTW_S:.0f} s"
