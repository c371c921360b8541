"""Asset checks on every aviation table: declared schema, time order, exact step, positions, phase order."""

import dagster as dg
import polars as pl

from models.aviation.phases import PHASES
from assets.checks import schema_checks
from warehouse.storage import read_table

AVIATION_TABLES = (
    "flight_tracks", "flights", "ingest_rejects", "ingest_summary", "weather",
    "tracks_20s", "flight_phases", "trajectory_modes", "flight_splits",
)


def _failures(df: pl.DataFrame, bad: pl.Expr, what: str) -> dg.AssetCheckResult:
    offenders = df.filter(bad)
    return dg.AssetCheckResult(
        passed=offenders.height == 0,
        metadata={what: offenders.height, "examples": dg.MetadataValue.json(offenders["flight_id"].unique().head(5).to_list())},
    )


def _monotonic_check(table: str) -> dg.AssetChecksDefinition:
    @dg.asset_check(asset=table, name="time_strictly_increasing", description="time strictly increases within every flight")
    def check() -> dg.AssetCheckResult:
        t = read_table(table)
        return _failures(t, (pl.col("ts").diff().over("flight_id") <= pl.duration(seconds=0)).fill_null(False), "non_increasing_steps")

    return check


@dg.asset_check(asset="ingest_summary", description="rows read = kept + rejected, per source")
def ingest_rows_accounted() -> dg.AssetCheckResult:
    s = read_table("ingest_summary")
    per = s.group_by("source").agg(
        read=pl.col("rows").filter(pl.col("outcome") == "read").sum(),
        accounted=pl.col("rows").filter(pl.col("outcome") != "read").sum(),
    )
    rejects = read_table("ingest_rejects").height
    ok = per.filter(pl.col("read") != pl.col("accounted")).height == 0 and rejects == s.filter(pl.col("outcome") == "rejected")["rows"].sum()
    return dg.AssetCheckResult(passed=ok, metadata={"sources": dg.MetadataValue.json(per.to_dicts()), "quarantined_rows": rejects})


@dg.asset_check(asset="tracks_20s", description="every step is exactly the configured Δt (the most common step)")
def tracks_exact_step() -> dg.AssetCheckResult:
    t = read_table("tracks_20s").with_columns(step=pl.col("ts").diff().over("flight_id"))
    if t["step"].drop_nulls().is_empty():
        return dg.AssetCheckResult(passed=False, metadata={"points": t.height, "why": "no flight has two points: no step to check"})
    dt = t["step"].drop_nulls().mode().sort()[0]
    result = _failures(t, pl.col("step").is_not_null() & (pl.col("step") != dt), "off_step_points")
    return dg.AssetCheckResult(passed=result.passed, metadata={**result.metadata, "step_s": dt.total_seconds()})


@dg.asset_check(asset="tracks_20s", description="no missing or NaN position, altitude or weather value")
def tracks_no_missing_values() -> dg.AssetCheckResult:
    t = read_table("tracks_20s")
    cols = ["lat", "lon", "alt_m", "temperature_k", "wind_u_mps", "wind_v_mps"]
    return _failures(t, pl.any_horizontal(pl.col(c).is_null() | pl.col(c).is_nan() for c in cols), "points_with_missing_values")


@dg.asset_check(asset="tracks_20s", description="phases appear only in the order climb -> cruise -> descent")
def tracks_phase_order() -> dg.AssetCheckResult:
    rank = pl.col("phase").replace_strict({p: i for i, p in enumerate(PHASES)}, default=-1, return_dtype=pl.Int8)
    t = read_table("tracks_20s").with_columns(rank=rank)
    return _failures(t, (pl.col("rank") < 0) | (pl.col("rank").diff().over("flight_id") < 0).fill_null(False), "out_of_order_points")


@dg.asset_check(asset="trajectory_modes", description="every mode of a route split into several modes has at least two flights")
def modes_min_flights() -> dg.AssetCheckResult:
    sizes = read_table("trajectory_modes").group_by("route", "phase", "mode", "n_modes").agg(flights=pl.len())
    small = sizes.filter((pl.col("n_modes") > 1) & (pl.col("flights") < 2)).drop("n_modes").sort("route", "phase", "mode")
    return dg.AssetCheckResult(
        passed=small.height == 0,
        severity=dg.AssetCheckSeverity.WARN,
        metadata={"smallest_mode": int(sizes["flights"].min()), "modes_below_2": dg.MetadataValue.json(small.to_dicts())},
    )


CHECKS = schema_checks(AVIATION_TABLES) + [_monotonic_check(t) for t in ("flight_tracks", "tracks_20s")] + [
    ingest_rows_accounted,
    tracks_exact_step,
    tracks_no_missing_values,
    tracks_phase_order,
    modes_min_flights,
]
