"""DTW clustering of 1,000 cruise sub-trajectories in under 60 s (models.aviation.modes.cluster_series).

The sub-trajectories are real: the cruise phase of the first 1,000 flights of route UUEE-UMKK from a
scaled set (perturbed, time-shifted copies of the real flights, built like the 10,000-flight set) run
through our own chain (ingest -> 20 s grid -> phases). They are prepared as trajectory_modes prepares
them: every `stride`-th point of each flight (the default of trajectory_modes' `stride`, read from its
signature: 3 = one point a minute), (lon, lat, alt_m) min-max scaled over all points of the set. Then
cluster_series (normalised DTW matrix, Ward linkage, silhouette over k = 2..8) is timed, and only that.
Baseline in the same run: the same call on the first 100 series (~1/100 of the pairs).

TRAFFICLEARN_BENCH_DTW_FULL=1 also times every 20 s point (stride 1), for information (about 2 min).
"""

import inspect
import os
import time

import numpy as np
import polars as pl
import pytest

import benchlib as b

ROUTE = "UUEE-UMKK"  # 57 of the 93 real flights


def _modes():
    modes = pytest.importorskip("models.aviation.modes", reason="models/aviation/modes.py does not exist yet")
    if not hasattr(modes, "cluster_series"):
        pytest.skip("models.aviation.modes has no cluster_series yet")
    return modes


def _pipeline_stride(modes) -> int:
    p = inspect.signature(modes.trajectory_modes).parameters.get("stride") if hasattr(modes, "trajectory_modes") else None
    return int(p.default) if p is not None and p.default is not inspect.Parameter.empty else 1


@pytest.fixture(scope="module")
def route_points(tmp_path_factory, bench_results) -> pl.DataFrame:
    """20 s points (with phase) of the first DTW_SERIES flights of ROUTE that have a cruise phase."""
    n = b.DTW_SERIES
    path = tmp_path_factory.mktemp("bench_modes") / "scaled_for_dtw.parquet"
    info = b.write_scaled(path, (n // 57 + 2) * b.N_REAL_FLIGHTS, b.STEP_S, seed=2)
    run = b.run_chain(path, keep=True)
    route_ids = run.flights_table.filter(pl.col("route") == ROUTE)["flight_id"].implode()
    pts = (
        run.phases.filter(pl.col("flight_id").is_in(route_ids))
        .drop_nulls(["lon", "lat", "alt_m"])
        .sort("flight_id", "ts")
        .with_columns(pos=pl.int_range(pl.len()).over("flight_id"))
    )
    cruising = pts.filter(pl.col("phase") == "cruise")["flight_id"].unique(maintain_order=True).head(n)
    bench_results["dtw_input"] = {"scaled_set": info, "route": ROUTE, "flights": cruising.len()}
    return pts.filter(pl.col("flight_id").is_in(cruising.implode()))


def _series(pts: pl.DataFrame, stride: int) -> list[np.ndarray]:
    """Cruise sub-trajectories as trajectory_modes builds them (stride over the whole flight, then phase)."""
    sub = (
        pts.filter(pl.col("pos") % stride == 0)
        .filter(pl.col("phase") == "cruise")
        .filter(pl.len().over("flight_id") >= 2)
    )
    lens = sub.group_by("flight_id", maintain_order=True).len()["len"].to_numpy()
    x = sub.select("lon", "lat", "alt_m").to_numpy().astype(np.float64)
    lo, span = x.min(axis=0), np.ptp(x, axis=0)
    x = np.ascontiguousarray((x - lo) / np.where(span > 0, span, 1.0))
    return np.split(x, np.cumsum(lens)[:-1])


def _time_clustering(modes, series: list[np.ndarray]) -> tuple[float, object]:
    t = time.perf_counter()
    c = modes.cluster_series(series, max_modes=8)
    return time.perf_counter() - t, c


def test_dtw_clustering_1000_subtrajectories(route_points, bench_results):
    modes = _modes()
    stride = _pipeline_stride(modes)
    series = _series(route_points, stride)
    n = len(series)
    assert n >= b.DTW_SERIES, f"only {n} cruise sub-trajectories on {ROUTE}, wanted {b.DTW_SERIES}"
    lens = np.array([len(s) for s in series])

    base_s, _ = _time_clustering(modes, series[:100])
    load = b.warn_if_busy(f"DTW clustering of {n} series")
    took, c = _time_clustering(modes, series)

    pairs, base_pairs = n * (n - 1) // 2, 100 * 99 // 2
    record = {
        "series": n,
        "pairs": pairs,
        "stride": stride,
        "points_per_series": {"mean": round(float(lens.mean()), 1), "min": int(lens.min()), "max": int(lens.max())},
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
    bench_results["dtw_clustering"] = record
    print(
        f"\nBENCH DTW clustering of {n:,} cruise sub-trajectories ({ROUTE}, every {stride * 20} s as trajectory_modes "
        f"uses, mean {lens.mean():.0f} points, {pairs:,} pairs): {b.fmt_s(took)} (target < {b.TARGET_DTW_S:.0f} s, "
        f"{took / b.TARGET_DTW_S:.2f}x the budget); {c.n_modes} modes, silhouette "
        f"{c.silhouette if c.silhouette is None else round(c.silhouette, 3)}; baseline 100 series {b.fmt_s(base_s)}, "
        f"ratio {took / max(base_s, 1e-9):.0f}x for {pairs / base_pairs:.0f}x the pairs"
    )

    if os.environ.get("TRAFFICLEARN_BENCH_DTW_FULL") == "1" and stride != 1:
        full = _series(route_points, 1)
        full_s, cf = _time_clustering(modes, full)
        flens = np.array([len(s) for s in full])
        record["every_20s_point"] = {"seconds": round(full_s, 3), "mean_points": round(float(flens.mean()), 1), "n_modes": int(cf.n_modes)}
        print(
            f"BENCH DTW clustering of {len(full):,} cruise sub-trajectories at every 20 s point (mean {flens.mean():.0f} "
            f"points): {b.fmt_s(full_s)}, {cf.n_modes} modes (information only)"
        )

    assert took < b.TARGET_DTW_S, f"DTW clustering of {n} sub-trajectories took {took:.1f} s, target < {b.TARGET_DTW_S:.0f} s"
