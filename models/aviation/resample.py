"""Constant-step tracks: every flight on a grid of multiples of Δt (default 20 s).

Between two received positions the aircraft is assumed to fly at constant speed, i.e. positions,
altitude and rates are linear in time, angles (track, longitude) turn along the shorter arc. All flights
are interpolated at once, each grid point's row found once (kernels.grid_rows) and every
column interpolated from it (kernels.interpolate).
"""

from functools import partial

import numpy as np
import polars as pl

from models.aviation import kernels
from models.aviation.order import in_flight_order, run_ends, run_starts
from models.parallel import together
from models.units import EARTH_RADIUS_KM

EARTH_RADIUS_M = EARTH_RADIUS_KM * 1000.0
US = 1_000_000


def _grid(first_us: np.ndarray, last_us: np.ndarray, dt_us: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(flight index, grid time in µs) of all grid points of all flights, and each flight's first grid point (one more
    at the end: the count), without a Python loop."""
    start = -(-first_us // dt_us) * dt_us  # ceil to the step
    stop = last_us // dt_us * dt_us
    n = np.maximum((stop - start) // dt_us + 1, 0)
    owner = np.repeat(np.arange(len(n)), n)
    offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return owner, start[owner] + offset * dt_us, np.r_[0, np.cumsum(n)]


def resample(tracks: pl.DataFrame, dt_s: float = 20.0) -> pl.DataFrame:
    """Cleaned points (flight_id, ts, lat, lon, alt_m, groundspeed_mps, track_deg, vertical_rate_mps)
    -> the same columns on the Δt grid. Flights shorter than one step are dropped."""
    dt_us = int(round(dt_s * US))
    if dt_us <= 0:  # a zero step is one point per flight, a negative one no points: never a table to keep
        raise ValueError(f"dt_s must be a positive step in seconds, got {dt_s:g}")
    src = in_flight_order(tracks)
    # flights are contiguous after the sort: their first rows without hashing the string ids
    starts = run_starts(src["flight_id"])
    t = src["ts"].dt.epoch("us").to_numpy()
    ids = src["flight_id"].gather(starts)
    ends = run_ends(starts, len(t))
    owner, grid_us, grid_first = _grid(t[starts], t[ends - 1], dt_us)
    for a in (t, starts, ends, grid_first, grid_us):  # one compiled signature whether polars lent memory or copied it
        a.setflags(write=False)
    row = kernels.grid_rows(t, starts, ends, grid_first, grid_us)

    def interp(column: str, turn: float = 0.0) -> np.ndarray:
        """np.interp over each flight's valid values, gaps outside them (kernels.interpolate); with `turn` (360) an
        angle, interpolated along the shorter arc (not wrapped)."""
        values = src[column].cast(pl.Float64).fill_null(np.nan).to_numpy()
        values.setflags(write=False)
        out = np.empty(len(grid_us))
        kernels.interpolate(t, starts, ends, grid_first, grid_us, row, values, turn, out)
        return out

    # angles turn the shorter way: across the antimeridian (179 -> -179), through north (359 -> 1 deg)
    turns = {"lat": 0.0, "lon": 360.0, "alt_m": 0.0, "groundspeed_mps": 0.0, "track_deg": 360.0, "vertical_rate_mps": 0.0}
    grid = dict(zip(turns, together(*(partial(interp, c, turn) for c, turn in turns.items()))))  # the kernel releases the GIL
    grid["lon"] = (grid["lon"] + 180.0) % 360.0 - 180.0
    grid["track_deg"] %= 360.0
    out = pl.DataFrame(
        {
            "flight_id": ids.gather(owner).set_sorted(),  # in order: flagged, so that checks downstream are free
            "ts": pl.Series(grid_us).cast(pl.Datetime("us", "UTC")),
            **grid,
        }
    )
    return fill_rates_from_positions(out, dt_s)


def fill_rates_from_positions(df: pl.DataFrame, dt_s: float) -> pl.DataFrame:
    """Where a source reported no speed/track/vertical rate, derive them from consecutive positions.

    Rows are grouped by flight in time order (as `resample` makes them)."""
    rates = ["groundspeed_mps", "track_deg", "vertical_rate_mps"]
    if not df.select((pl.col(rates).is_nan() | pl.col(rates).is_null()).any()).to_numpy().any():
        return df  # the usual case: nothing to derive
    # whether the next (-1) / previous (1) row is of the same flight: a shift guarded by it is a window shift over
    # flight_id on grouped rows, without the window's grouping
    same = {k: (pl.col("flight_id") == pl.col("flight_id").shift(k)).fill_null(False) for k in (-1, 1)}
    near = lambda c, k: pl.when(same[k]).then(c.shift(k)).otherwise(c)  # noqa: E731  (else this row's value)
    lat, lon, alt = pl.col("lat").radians(), pl.col("lon").radians(), pl.col("alt_m")
    nlat, nlon, plat, plon = near(lat, -1), near(lon, -1), near(lat, 1), near(lon, 1)
    steps = (same[-1].cast(pl.Float64) + same[1].cast(pl.Float64)).clip(lower_bound=1.0)
    dlat, dlon = nlat - plat, nlon - plon
    a = (dlat / 2).sin() ** 2 + plat.cos() * nlat.cos() * (dlon / 2).sin() ** 2
    dist = 2 * EARTH_RADIUS_M * a.sqrt().arcsin()
    bearing = pl.arctan2(dlon.sin() * nlat.cos(), plat.cos() * nlat.sin() - plat.sin() * nlat.cos() * dlon.cos()).degrees() % 360
    return df.with_columns(
        pl.col("groundspeed_mps").fill_nan(None).fill_null(dist / (steps * dt_s)),
        pl.col("track_deg").fill_nan(None).fill_null(bearing),
        pl.col("vertical_rate_mps").fill_nan(None).fill_null((near(alt, -1) - near(alt, 1)) / (steps * dt_s)),
    )
