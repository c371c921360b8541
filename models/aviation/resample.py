"""Constant-step tracks: every flight on a grid of multiples of Δt (default 20 s).

Between two received positions the aircraft is assumed to fly at constant speed, i.e. positions,
altitude and rates are linear in time, angles (track, longitude) turn along the shorter arc. All flights
are interpolated at once: each flight's times are offset by its index times a stride longer than any
flight, which makes the concatenated time axis strictly increasing without letting one flight bleed into
the next, and one binary search of the grid in that axis serves every column.
"""

import numpy as np
import polars as pl

from models.aviation.order import in_flight_order, runs
from models.units import EARTH_RADIUS_KM

EARTH_RADIUS_M = EARTH_RADIUS_KM * 1000.0
US = 1_000_000


def _grid(first_us: np.ndarray, last_us: np.ndarray, dt_us: int) -> tuple[np.ndarray, np.ndarray]:
    """(flight index, grid time in µs) for all grid points of all flights, without a Python loop."""
    start = -(-first_us // dt_us) * dt_us  # ceil to the step
    stop = last_us // dt_us * dt_us
    n = np.maximum((stop - start) // dt_us + 1, 0)
    owner = np.repeat(np.arange(len(n)), n)
    offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return owner, start[owner] + offset * dt_us


def resample(tracks: pl.DataFrame, dt_s: float = 20.0) -> pl.DataFrame:
    """Cleaned points (flight_id, ts, lat, lon, alt_m, groundspeed_mps, track_deg, vertical_rate_mps)
    -> the same columns on the Δt grid. Flights shorter than one step are dropped."""
    dt_us = int(round(dt_s * US))
    if dt_us <= 0:  # a zero step is one point per flight, a negative one no points: never a table to keep
        raise ValueError(f"dt_s must be a positive step in seconds, got {dt_s:g}")
    src = in_flight_order(tracks)
    # flights are contiguous after the sort: run ids number them without hashing the string ids
    idx, starts = runs(src["flight_id"])
    t = src["ts"].dt.epoch("us").to_numpy()
    ids = src["flight_id"].gather(starts)
    first_us = t[starts]
    last_us = t[np.r_[starts[1:] - 1, len(t) - 1]] if len(t) else t
    owner, grid_us = _grid(first_us, last_us, dt_us)

    t0 = t.min() if len(t) else 0
    stride = float((t.max() - t0) if len(t) else 0) + 10.0 * dt_us
    key_src = idx * stride + (t - t0)
    key_dst = owner * stride + (grid_us - t0)

    # the grid's binary search over all rows; a column with gaps derives its own from it
    j_all = np.clip(np.searchsorted(key_src, key_dst, side="right") - 1, 0, len(key_src) - 1)
    searches: dict[bytes, tuple] = {}  # one search per distinct set of valid points, shared by columns

    def search(ok: np.ndarray) -> tuple:
        """(left, right source row, offset from left, left-to-right span, gap mask) of every grid point."""
        everywhere = ok.all()
        mask_key = b"" if everywhere else np.packbits(ok).tobytes()
        if mask_key not in searches:
            gap = None
            if everywhere:
                j, k = j_all, np.minimum(j_all + 1, len(key_src) - 1)
            else:
                # the search among the valid rows only: the last valid row up to the one the full search found (else
                # the first valid row), and the valid row after it; looked up for the grid points, not the rows
                pos = np.flatnonzero(ok)
                at = np.clip(np.searchsorted(pos, j_all, side="right") - 1, 0, len(pos) - 1)
                j, k = pos[at], pos[np.minimum(at + 1, len(pos) - 1)]
                # outside a flight's first/last reported value there is nothing to interpolate from: leave a gap.
                # Before the first: j is in an earlier flight or later than the point; after the last: j is earlier
                # and the last valid row of its flight
                gap = (idx[j] != owner) | (key_src[j] > key_dst) | ((key_dst > key_src[j]) & ((k == j) | (idx[k] != owner)))
            searches[mask_key] = (j, k, key_dst - key_src[j], key_src[k] - key_src[j], gap)
        return searches[mask_key]

    def interp(values: np.ndarray, turn: float | None = None) -> np.ndarray:
        """np.interp over each flight's valid values (bit-identical: its slope-times-offset arithmetic and the
        left value on an exact hit); with `turn` (360) an angle, interpolated along the shorter arc (not wrapped)."""
        ok = ~np.isnan(values)
        if not ok.any():
            return np.full(len(key_dst), np.nan)
        j, k, dx, h, gap = search(ok)
        rise = values[k] - values[j]
        if turn is not None:
            rise = (rise + turn / 2) % turn - turn / 2
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(dx == 0, values[j], rise / h * dx + values[j])
        if gap is not None:
            out[gap] = np.nan
        return out

    col = lambda c: src[c].cast(pl.Float64).fill_null(np.nan).to_numpy()  # noqa: E731
    out = pl.DataFrame(
        {
            "flight_id": ids.gather(owner).set_sorted(),  # in order: flagged, so that checks downstream are free
            "ts": pl.Series(grid_us).cast(pl.Datetime("us", "UTC")),
            "lat": interp(col("lat")),
            # across the antimeridian (179 -> -179) the shorter arc is the one the aircraft flew
            "lon": (interp(col("lon"), turn=360.0) + 180.0) % 360.0 - 180.0,
            "alt_m": interp(col("alt_m")),
            "groundspeed_mps": interp(col("groundspeed_mps")),
            # a heading of 359 deg then 1 deg turns through north
            "track_deg": interp(col("track_deg"), turn=360.0) % 360.0,
            "vertical_rate_mps": interp(col("vertical_rate_mps")),
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
