"""Checks of the trajectory tables: declared schemas, and domain rules on the results."""

import dagster as dg
import polars as pl

from assets.checks import schema_checks
from models.aviation.phases import PHASES
from warehouse.tables.trajectory import TABLES
from warehouse.storage import read_table

_TABLES = [t.name for t in TABLES]


@dg.asset_check(asset="trajectory_metrics", name="every_method_has_every_phase", description="each method has total and per-phase 3D RMSE")
def every_method_has_every_phase() -> dg.AssetCheckResult:
    m = read_table("trajectory_metrics").filter(pl.col("metric") == "rmse_3d_nm")
    per = m.group_by("method", "scheme").agg(pl.col("phase").n_unique().alias("phases"))
    missing = per.filter(pl.col("phases") < len(PHASES) + 1)  # climb, cruise, descent and total
    return dg.AssetCheckResult(passed=missing.is_empty(), metadata={"incomplete": dg.MetadataValue.json(missing.rows())})


@dg.asset_check(asset="mode_posteriors", name="posteriors_sum_to_one", description="per method, phase, true mode and seed-mean, probabilities sum to 1")
def posteriors_sum_to_one() -> dg.AssetCheckResult:
    p = read_table("mode_posteriors").group_by("method", "scheme", "phase", "true_mode").agg(pl.col("mean_probability").sum().alias("s"))
    bad = p.filter((pl.col("s") - 1).abs() > 1e-6)
    return dg.AssetCheckResult(passed=bad.is_empty(), metadata={"bad_rows": bad.height})


@dg.asset_check(asset="trajectory_predictions", name="predictions_for_every_test_flight",
                description="every method and seed predicts every test flight")
def predictions_for_every_test_flight() -> dg.AssetCheckResult:
    test = read_table("flight_splits").filter(pl.col("split") == "test")["flight_id"].n_unique()
    per = read_table("trajectory_predictions").group_by("method", "scheme", "seed").agg(pl.col("flight_id").n_unique().alias("n"))
    short = per.filter(pl.col("n") < test)
    return dg.AssetCheckResult(passed=short.is_empty(), metadata={"test_flights": test, "short": dg.MetadataValue.json(short.rows())})


CHECKS = schema_checks(_TABLES) + [every_method_has_every_phase, posteriors_sum_to_one, predictions_for_every_test_flight]
