"""Seeded train/test split by flight, stratified by route and whole-trajectory mode.

Stratifying keeps every mode represented on both sides where it has at least two flights, so the
learners see each modality in training and are scored on held-out flights of each.
"""

import polars as pl


def split_flights(flights: pl.DataFrame, modes: pl.DataFrame, test_fraction: float = 0.2, seed: int = 0) -> pl.DataFrame:
    """flights (flight_id, route) + trajectory_modes -> flight_splits (flight_id, route, split, seed)."""
    if not 0.0 < test_fraction < 1.0:
        raise ValueError(f"test_fraction must be strictly between 0 and 1, got {test_fraction}")
    whole = modes.filter(pl.col("phase") == "all").select("flight_id", "mode")
    strata = flights.select("flight_id", "route").join(whole, on="flight_id", how="left").sort("flight_id")
    n = pl.len().over("route", "mode")
    n_test = (n * test_fraction).round().clip(lower_bound=1).cast(pl.Int64)
    rank = pl.int_range(pl.len()).shuffle(seed=seed).over("route", "mode")
    is_test = (n >= 2) & (rank < n_test)
    return strata.select(
        "flight_id",
        "route",
        split=pl.when(is_test).then(pl.lit("test")).otherwise(pl.lit("train")),
        seed=pl.lit(seed, dtype=pl.Int64),
    )
