"""Flight phases climb -> cruise -> descent (thesis §7.4.1), for all flights at once.

`vertical` (the thesis's rules): per point ΔH, ΔT and ΔA (change of altitude rate) against the previous
point; the climbing flag is ΔH/ΔT > climb_rate_mps or ΔA/ΔT > 0. Climb ends at the first point where the
flag is false once more than 10 % of the route's estimated duration has elapsed. Descent starts at the
first point after the climb where the altitude drops by more than descent_drop_m per step once more than
65 % of the estimated duration has elapsed (a safety lock against level changes in cruise). The estimated
duration of a route is the median duration of its flights.

`regions` (the waypoint/region variant, §7.3, Fig 7.3): climb lasts until the aircraft first leaves a
circle of climb_radius_km around the origin, descent starts when it first enters a circle of
descent_radius_km around the destination.

Either way a flight's phases come in the order climb, cruise, descent; a phase may be absent.
"""

from dataclasses import dataclass

import numpy as np
import polars as pl

from models.aviation.order import in_flight_order, run_ends, run_starts
from models.units import EARTH_RADIUS_KM

PHASES = ("climb", "cruise", "descent")


@dataclass(frozen=True)
class PhaseConfig:
    method: str = "vertical"  # "vertical" (thesis rules) or "regions"
    climb_rate_mps: float = 2.5  # ~500 ft/min
    climb_end_fraction: float = 0.10
    descent_drop_m: float = 25.0  # per step; above the 7.6 m (25 ft) quantisation noise of baro altitude
    descent_start_fraction: float = 0.65
    smooth_points: int = 3  # centred rolling mean of altitude before differencing, damps noise
    climb_radius_km: float = 150.0
    descent_radius_km: float = 200.0


def _haversine_km(lat1: pl.Expr, lon1: pl.Expr, lat2: pl.Expr, lon2: pl.Expr) -> pl.Expr:
    dlat, dlon = (lat2 - lat1).radians(), (lon2 - lon1).radians()
    a = (dlat / 2).sin() ** 2 + lat1.radians().cos() * lat2.radians().cos() * (dlon / 2).sin() ** 2
    return 2 * EARTH_RADIUS_KM * a.sqrt().arcsin()


def _first_ts_where(cond: pl.Expr) -> pl.Expr:
    return pl.col("ts").filter(cond).min().over("_run")


def _vertical_bounds(tracks: pl.DataFrame, flights: pl.DataFrame, cfg: PhaseConfig) -> pl.DataFrame:
    duration = flights.select(
        "flight_id", "route", dur_s=(pl.col("last_ts") - pl.col("first_ts")).dt.total_seconds(fractional=True)
    ).with_columns(est_s=pl.col("dur_s").median().over("route"))
    f = "_run"
    # each window is materialised once: nested in one expression, polars would evaluate the inner ones again
    t = tracks.join(duration, on="flight_id", how="left", maintain_order="left").with_columns(
        _alt=pl.col("alt_m").rolling_mean(cfg.smooth_points, center=True, min_samples=1).over(f),
        _dt=pl.col("ts").diff().over(f).dt.total_seconds(fractional=True),
        _elapsed=(pl.col("ts") - pl.col("ts").first().over(f)).dt.total_seconds(fractional=True),
    )
    t = t.with_columns(_dh=pl.col("_alt").diff().over(f)).with_columns(_rate=pl.col("_dh") / pl.col("_dt"))
    t = t.with_columns(_da=pl.col("_rate").diff().over(f))
    climbing = ((pl.col("_rate") > cfg.climb_rate_mps) | (pl.col("_da") / pl.col("_dt") > 0)).fill_null(True)
    t = t.with_columns(climb_end=_first_ts_where(~climbing & (pl.col("_elapsed") > cfg.climb_end_fraction * pl.col("est_s"))))
    descending = (pl.col("_dh") < -cfg.descent_drop_m).fill_null(False) & (
        pl.col("_elapsed") > cfg.descent_start_fraction * pl.col("est_s")
    )
    return t.with_columns(descent_start=_first_ts_where(descending & (pl.col("ts") >= pl.col("climb_end"))))


def _region_bounds(tracks: pl.DataFrame, flights: pl.DataFrame, airports: pl.DataFrame, cfg: PhaseConfig) -> pl.DataFrame:
    ap = airports.select("icao", "lat", "lon")
    ends = flights.select("flight_id", "origin", "destination").join(
        ap.rename({"icao": "origin", "lat": "o_lat", "lon": "o_lon"}), on="origin", how="left"
    ).join(ap.rename({"icao": "destination", "lat": "d_lat", "lon": "d_lon"}), on="destination", how="left")
    t = tracks.join(ends, on="flight_id", how="left", maintain_order="left")
    from_origin = _haversine_km(pl.col("lat"), pl.col("lon"), pl.col("o_lat"), pl.col("o_lon"))
    to_dest = _haversine_km(pl.col("lat"), pl.col("lon"), pl.col("d_lat"), pl.col("d_lon"))
    t = t.with_columns(climb_end=_first_ts_where(from_origin.fill_null(float("inf")) > cfg.climb_radius_km))
    entering = (to_dest.fill_null(float("inf")) < cfg.descent_radius_km) & (pl.col("ts") >= pl.col("climb_end"))
    return t.with_columns(descent_start=_first_ts_where(entering))


def assign_phases(
    tracks: pl.DataFrame, flights: pl.DataFrame, cfg: PhaseConfig = PhaseConfig(), airports: pl.DataFrame | None = None
) -> pl.DataFrame:
    """Add a `phase` column to constant-step tracks; rows come back in (flight_id, ts) order."""
    # windows per flight over an integer run id (rows are grouped by flight) instead of hashing the string ids
    src = in_flight_order(tracks)
    starts = run_starts(src["flight_id"])
    run = pl.Series(np.repeat(np.arange(len(starts), dtype=np.uint32), run_ends(starts, src.height) - starts)).set_sorted()
    runs = src.with_columns(_run=run)  # flagged sorted: polars' windows over it then skip hashing
    if cfg.method == "vertical":
        t = _vertical_bounds(runs, flights, cfg)
    elif cfg.method == "regions":
        if airports is None:
            raise ValueError("phase method 'regions' needs the airports table")
        t = _region_bounds(runs, flights, airports, cfg)
    else:
        raise ValueError(f"unknown phase method '{cfg.method}', expected 'vertical' or 'regions'")
    phase = (
        pl.when(pl.col("climb_end").is_null() | (pl.col("ts") < pl.col("climb_end")))
        .then(pl.lit("climb"))
        .when(pl.col("descent_start").is_not_null() & (pl.col("ts") >= pl.col("descent_start")))
        .then(pl.lit("descent"))
        .otherwise(pl.lit("cruise"))
    )
    return t.with_columns(phase=phase).select(*tracks.columns, "phase")


def phase_table(tracks: pl.DataFrame) -> pl.DataFrame:
    """flight_phases: one row per flight and phase present, in phase order."""
    order = pl.col("phase").replace_strict({p: i for i, p in enumerate(PHASES)}, return_dtype=pl.Int8)
    return (
        tracks.group_by("flight_id", "phase")
        .agg(start_ts=pl.col("ts").min(), end_ts=pl.col("ts").max(), n_points=pl.len().cast(pl.Int64))
        .sort(pl.col("flight_id"), order)
    )
