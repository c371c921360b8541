"""The thesis's Table 6.1 protocol for AppLearn and the SVM BC baseline: datasets, runs, aggregation.

A dataset is one whole-flight cluster (route, mode) of `trajectory_modes` (the thesis's two BCN-MAD clusters);
each is split by partition P1-P4 and seed, both learners train on the training flights and roll out from every
test flight's first point in the heading environment. AppLearn's one data-driven choice, the DQN reward scale, is
made on validation flights carved from the training flights: the chosen model is the one trained on the rest
(the SVM, with nothing to choose, trains on all of them; both share the winner's geometry and NN_altitude).
"""

import time
from dataclasses import replace

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
# share of a run's training flights held out to choose the DQN reward scale (AppLearnParams.reward_scales)
VALIDATION_SHARE = 0.2
VALIDATION_STREAM = 1  # the validation draw's random stream, apart from the partition draw of the same seed


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


def validation_split(train_ids: list[str], seed: int) -> tuple[list[str], list[str]]:
    """(fit ids, validation ids) carved from the training flights, seeded; a single expert (P1) is validated in-sample."""
    if len(train_ids) < 2:
        return train_ids, train_ids
    order = np.random.default_rng([seed, VALIDATION_STREAM]).permutation(sorted(train_ids)).tolist()
    n_val = max(1, round(VALIDATION_SHARE * len(order)))
    return sorted(order[n_val:]), sorted(order[:n_val])


def select_reward_scale(train: pl.DataFrame, weather: pl.DataFrame, params: AppLearnParams, seed: int, log=None):
    """AppLearn trained with each of params.reward_scales on the fit flights, scored on the validation flights
    (highest success rate, then lowest RMSE); returns the winner and its training history. It sees no test flight.
    With a single candidate nothing is chosen and the model trains on every training flight."""
    if len(params.reward_scales) < 2:
        return train_applearn(train, weather, replace(params, reward_scale=params.reward_scales[0]), seed, log=log)
    fit_ids, val_ids = validation_split(sorted(train["flight_id"].unique().to_list()), seed)
    fit, val = (train.filter(pl.col("flight_id").is_in(ids)) for ids in (fit_ids, val_ids))
    candidates = []
    for scale in params.reward_scales:
        model, history = train_applearn(fit, weather, replace(params, reward_scale=scale), seed, log=log)
        per_flight, _ = evaluate_policy(model.env(weather), model.policy, val)
        candidates.append((model, history, {"reward_scale": scale, "success_rate": float(per_flight["success"].mean()),
                                            "rmse_3d_km": float(per_flight["rmse_3d_nm"].mean()) * KM_PER_NM}))
    model, history, _ = min(candidates, key=lambda c: (-c[2]["success_rate"], c[2]["rmse_3d_km"]))
    model.validation = {"flights": val_ids, "scores": [score for _, _, score in candidates]}
    return model, history


def run_partition(tracks: pl.DataFrame, weather: pl.DataFrame, partition: str, seed: int, params: AppLearnParams, log=None):
    """Train AppLearn (reward scale chosen on validation flights) and the SVM on one partition draw;
    returns (model, model row, result rows)."""
    train_ids, test_ids = partition_flights(tracks, partition, seed)
    train, test = (tracks.filter(pl.col("flight_id").is_in(ids)) for ids in (train_ids, test_ids))
    t0 = time.perf_counter()
    model, history = select_reward_scale(train, weather, params, seed, log=log)
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


def run_partition_job(job: tuple) -> tuple[bytes, dict, list[dict]]:
    """`run_partition(tracks, weather, partition, seed, params)` for a worker process: the model comes back as
    its file's bytes. Every run seeds its own randomness, so the result does not depend on where it ran."""
    model, row, results = run_partition(*job)
    return model.to_bytes(), row, results


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

