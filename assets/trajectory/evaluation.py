"""Evaluation on the held-out flights: every catalogued model reloaded from its file, plus the baselines.

trajectory_models -> trajectory_predictions, trajectory_metrics, trajectory_error_growth, mode_posteriors
"""

import time

import dagster as dg
import polars as pl
from pydantic import Field

_OUTS = ("trajectory_predictions", "trajectory_metrics", "trajectory_error_growth", "mode_posteriors")


class TrajectoryEvaluationConfig(dg.Config):
    dt_s: float = Field(default=20.0, description="time step of the tracks; must match the models' [s]")
    workers: int | None = Field(default=None, description="models evaluated in parallel, one process (one core) each [None: the usable cores]")


@dg.multi_asset(
    group_name="trajectory",
    outs={name: dg.AssetOut(description=desc) for name, desc in zip(_OUTS, (
        "Predicted trajectories of every test flight by every method and seed.",
        "Errors on the test flights per method, scheme, phase and metric: mean ± std over seeds.",
        "Error per minute of look-ahead per method and phase (Figs 7.11-7.13).",
        "Mean selector/posterior probabilities by true mode (Tables 7.6-7.8).",
    ))},
)
def trajectory_evaluation(context: dg.AssetExecutionContext, config: TrajectoryEvaluationConfig, trajectory_models: pl.DataFrame,
                          tracks_20s: pl.DataFrame, trajectory_modes: pl.DataFrame, flights: pl.DataFrame,
                          flight_splits: pl.DataFrame, weather: pl.DataFrame):
    import torch

    from models.markdown import markdown_table
    from models.parallel import ProcessPool, usable_cores
    from models.trajectory.evaluate import (evaluate_baselines, evaluate_model_file, growth_table, metrics_table,
                                            posterior_table, predictions_table)
    from models.trajectory.training import prepare

    torch.set_num_threads(1)  # small nets; with 2 threads on a busy 2-core machine OpenMP contention made training ~10x slower
    t0 = time.perf_counter()
    setup = prepare(tracks_20s, trajectory_modes, flights, flight_splits, weather, config.dt_s)
    res = evaluate_baselines(setup)
    n_test = len(setup.demos["all"][1].points)
    # each model is evaluated on one thread: the models share the cores as parallel processes, results in catalogue order
    with ProcessPool(config.workers or usable_cores(), evaluate_model_file) as pool:
        for k, (name, model_res) in enumerate(pool.iter([(setup, path) for path in trajectory_models["path"]]), 1):
            res.extend(model_res)
            context.log.info(f"[{k}/{trajectory_models.height}] evaluated {name} on {n_test} test flights")
    metrics = metrics_table(res.errors)
    headline = (metrics.filter((pl.col("phase") == "total") & pl.col("metric").is_in(["rmse_3d_nm", "eta_s", "success_rate"]))
                .with_columns((pl.col("mean").round(3).cast(pl.String) + " ± " + pl.col("std").round(3).cast(pl.String)).alias("v"))
                .pivot(on="metric", index=["method", "scheme"], values="v").sort("method", "scheme"))
    meta = {"test_flights": n_test, "models": trajectory_models.height,
            "seconds": round(time.perf_counter() - t0, 1), "total_errors": dg.MetadataValue.md(markdown_table(headline))}
    tables = (predictions_table(res.predictions), metrics, growth_table(res.growth), posterior_table(res.posteriors))
    return tuple(dg.Output(t, output_name=name, metadata=meta if name == "trajectory_metrics" else {}) for name, t in zip(_OUTS, tables))
