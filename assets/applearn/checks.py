"""Checks of the AppLearn tables: declared schemas, and that both methods ran on every partition draw."""

import dagster as dg
import polars as pl

from assets.checks import schema_checks
from warehouse.storage import read_table
from warehouse.tables.applearn import TABLES


@dg.asset_check(asset="applearn_results", name="both_methods_every_run", description="AppLearn and SVM BC have a result for every catalogued model")
def both_methods_every_run() -> dg.AssetCheckResult:
    runs = read_table("applearn_models").select("dataset", "partition", "seed")
    per = read_table("applearn_results").group_by("dataset", "partition", "seed").agg(pl.col("method").n_unique().alias("m"))
    missing = runs.join(per.filter(pl.col("m") == 2), on=["dataset", "partition", "seed"], how="anti")
    return dg.AssetCheckResult(passed=missing.is_empty(), metadata={"missing": dg.MetadataValue.json(missing.rows())})


CHECKS = schema_checks([t.name for t in TABLES]) + [both_methods_every_run]
