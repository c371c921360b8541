"""The thesis's Table 6.1 protocol for AppLearn and the SVM BC baseline: datasets, runs, aggregation.

A dataset is one whole-flight cluster (route, mode) of `trajectory_modes` (the thesis's two BCN-MAD clusters);
each is split by partition P1-P4 and seed, both learners train on the same expert flights and roll out from
every test flight's first point in the heading environment (same geometry and NN_altitude for both).
"""

import time

import numpy as np
import polars as pl

from models.trajectory.applearn import AppLearnParams, train_applearn
from models.trajectory.heading_env import (
    PARTITIONS,
    TrajectoryDataError,
    evaluate_policy,
    partition_flights,
)
from models.trajectory.metrics import haversine_km
from models.trajectory.svm_bc import train_svm_bc

KM_PER_NM = 1.852


def datasets(tracks: pl.DataFrame, modes: pl.DataFrame, min_flights: int) -> dict[str, pl.DataFrame]:
    """'<route>/<mode>' -> its flights' tracks, for every whole-flight cluster with at least min_flights flights."""
    clusters = modes.filter(pl.col("phase") == "all").group_by("route", "mode").agg("flight_id").filter(
        pl.col("flight_id").list.len() >= min_flights).sort("route", "mode")
    if clusters.height == 0:
        raise TrajectoryDataError(f"no whole-flight cluster has >= {min_flights} flights (trajectory_modes, phase 'all')")
    return {f"{r['route']}/{r['mode']}": tracks.filter(pl.col("flight_id").is_in(r["flight_id"])).sort("flight_id", "ts")
            for r in clusters.iter_rows(named=True)}


def expert_reaches_goal(test_tracks: pl.DataFrame, goal_lon: float, goal_lat: float, radius_km: float) -> float:
    """Share of the actual flights that come within the goal radius at some point (coverage often ends before)."""
    d = haversine_km(test_tracks.select("lon", "lat").to_numpy(), np.array([goal_lon, goal_lat]))
    return float(test_tracks.with_columns(d=d).group_by("flight_id").agg(pl.col("d").min())["d"].le(radius_km).mean())


def run_partition(tracks: pl.DataFrame, weather: pl.DataFrame, partition: str, seed: int, params: AppLearnParams, log=None):
    """Train AppLearn and the SVM on one partition draw; returns (model, model row, result rows)."""
    train_ids, test_ids = partition_flights(tracks, partition, seed)
    train, test = (tracks.filter(pl.col("flight_id").is_in(ids)) for ids in (train_ids, test_ids))
    t0 = time.perf_counter()
    model, history = train_applearn(train, weather, params, seed, log=log)
    train_s = time.perf_counter() - t0
    svm = train_svm_bc(train, model.geometry, model.altitude, seed)
    env = model.env(weather)
    g = model.geometry
    reference = expert_reaches_goal(test, g.goal_lon, g.goal_lat, g.goal_radius_km)
    results = []
    for method, policy in (("applearn", model.policy), ("svm_bc", svm.policy)):
        per_flight, _ = evaluate_policy(env, policy, test)
        results.append({
            "partition": partition, "method": method, "seed": seed, "n_test": per_flight.height,
            "success_rate": float(per_flight["success"].mean()), "expert_success_rate": reference,
            "rmse_3d_km": float(per_flight["rmse_3d_nm"].mean()) * KM_PER_NM, "rmse_3d_nm": float(per_flight["rmse_3d_nm"].mean()),
            "cte_nm": float(per_flight["cte_nm"].mean()), "vertical_ft": float(per_flight["vertical_ft"].mean()),
            "mean_steps": float(per_flight["steps"].mean()),
        })
    last = history.row(-1, named=True) if history.height else {"margin": float("nan"), "success_rate": float("nan")}
    row = {"partition": partition, "seed": seed, "episodes": params.episodes, "n_train": len(train_ids),
           "irl_steps": history.height, "final_margin": last["margin"], "final_train_success": last["success_rate"],
           "train_s": train_s}
    return model, row, results


def table_6_1(results: pl.DataFrame) -> pl.DataFrame:
    """Table 6.1 for our data: success rate (%) and RMSE (km) of both methods, mean ± std over seeds."""
    agg = results.group_by("dataset", "partition", "method").agg(
        (pl.col("success_rate") * 100).mean().alias("s"), (pl.col("success_rate") * 100).std().fill_null(0).alias("s_sd"),
        pl.col("rmse_3d_km").mean().alias("r"), pl.col("rmse_3d_km").std().fill_null(0).alias("r_sd"),
        pl.len().alias("seeds"), (pl.col("expert_success_rate") * 100).mean().alias("e"))
    fmt = lambda m, sd: pl.format("{} ± {}", pl.col(m).round(1), pl.col(sd).round(1))  # noqa: E731
    wide = agg.with_columns(success=fmt("s", "s_sd"), rmse=fmt("r", "r_sd")).pivot(
        on="method", index=["dataset", "partition", "seeds", "e"], values=["success", "rmse"])
    order = pl.col("partition").replace_strict({p: i for i, p in enumerate(PARTITIONS)}, return_dtype=pl.Int64)
    return wide.sort(pl.col("dataset"), order).select(
        "dataset", "partition", "seeds",
        pl.col("success_applearn").alias("success % AppLearn"), pl.col("success_svm_bc").alias("success % SVM BC"),
        pl.col("rmse_applearn").alias("RMSE km AppLearn"), pl.col("rmse_svm_bc").alias("RMSE km SVM BC"),
        pl.col("e").round(1).alias("actual flights reaching the goal %"))

