"""Asset checks of the urban tables: schemas, and the domain rules the issue states."""

import dagster as dg
import polars as pl

from assets.checks import schema_checks
from models.urban.network import SIGNAL_FREE_TYPES, junction_census
from warehouse.storage import read_table

TABLES = ["urban_routes", "urban_scenarios", "urban_training", "urban_results", "urban_trajectories", "urban_thesis_tables", "urban_comparisons"]


@dg.asset_check(asset="urban_routes", description="every network is unsignalized: no traffic lights, only right_before_left junctions")
def networks_unsignalized() -> dg.AssetCheckResult:
    bad = {}
    for path in read_table("urban_routes")["net_path"].unique():
        c = junction_census(path)
        if c.traffic_lights or set(c.types) - SIGNAL_FREE_TYPES:
            bad[path] = c.types
    return dg.AssetCheckResult(passed=not bad, metadata={"offending": dg.MetadataValue.json(bad)})


@dg.asset_check(asset="urban_scenarios", description="training and evaluation copies never share a demand seed")
def eval_copies_held_out() -> dg.AssetCheckResult:
    df = read_table("urban_scenarios")
    shared = set(df.filter(pl.col("role") == "train")["demand_seed"]) & set(df.filter(pl.col("role") != "train")["demand_seed"])
    return dg.AssetCheckResult(passed=not shared, metadata={"shared_seeds": dg.MetadataValue.json(sorted(shared))})


@dg.asset_check(asset="urban_results",
                description="issue target: col-MARL has zero collisions and zero teleports on every evaluation copy")
def col_marl_collision_free() -> dg.AssetCheckResult:
    df = read_table("urban_results").filter(pl.col("method") == "col_marl")
    bad = df.filter((pl.col("collisions") > 0) | (pl.col("teleports") > 0))
    return dg.AssetCheckResult(passed=bad.is_empty(), severity=dg.AssetCheckSeverity.WARN, metadata={
        "runs": df.height, "runs_with_collision_or_teleport": bad.height,
        "where": dg.MetadataValue.json(bad.select("scenario", "copy", "seed", "collisions", "teleports").to_dicts())})


CHECKS = [*schema_checks(TABLES), networks_unsignalized, eval_copies_held_out, col_marl_collision_free]
