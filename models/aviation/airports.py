"""Origin and destination airports of flights, from their first and last points.

Real coverage often starts after take-off and ends in descent well before landing (the Kaliningrad
flights stop 12-161 NM short of UMKK), so the nearest airport is often wrong: a small airfield lies
under the track. Candidates are therefore the airports of openap's table that have an instrument landing
system in openap's nav.dat (where airliners land), all airports only where none is in range. A low end
point (within a 3-degree path of the ground, i.e. in the terminal area where aircraft are vectored in any
direction) takes the nearest candidate; a high one scores the candidates ahead of it (behind it, for the
origin) by cross-track distance plus the mismatch between the distance to go and the distance a 3-degree
path from its altitude needs. Flights sharing a callsign fly the same route, so the per-flight answers
are then put to a majority vote per callsign; the distance to the chosen airport is recorded so a user
can see how far coverage stopped short.
"""

from functools import lru_cache
from pathlib import Path

import numpy as np
import polars as pl
from scipy.spatial import cKDTree

from models.aviation.order import in_flight_order, run_ends, run_starts
from models.units import EARTH_RADIUS_KM, M_PER_FT, M_PER_NM

EARTH_RADIUS_NM = EARTH_RADIUS_KM * 1000.0 / M_PER_NM
SEARCH_RADIUS_NM = 300.0
FT_PER_NM_PATH = 318.0  # a 3-degree glide path loses 318 ft per NM
MAX_OFF_TRACK_DEG = 60.0


TERMINAL_AREA_NM = 40.0  # a 3-degree path this long starts at ~12,700 ft


def _openap_nav() -> Path:
    import openap

    return Path(openap.__file__).parent / "data" / "nav"


@lru_cache(maxsize=1)
def airports_table() -> pl.DataFrame:
    """openap's airports (icao, lat, lon) with `ils`: the airport has an ILS or localizer in nav.dat."""
    ap = pl.read_csv(_openap_nav() / "airports.csv", columns=["icao", "lat", "lon"], schema_overrides={"icao": pl.String})
    # nav.dat rows of type 4 (ILS) and 5 (localizer) name their airport in the 9th field
    lines = (_openap_nav() / "nav.dat").read_text(encoding="latin-1").splitlines()
    ils = {f[8] for f in (line.split() for line in lines) if len(f) > 8 and f[0] in ("4", "5")}
    return ap.drop_nulls().with_columns(ils=pl.col("icao").is_in(list(ils)))


@lru_cache(maxsize=1)
def _airport_positions() -> dict[str, tuple[float, float]]:
    return {icao: (lat, lon) for icao, lat, lon in airports_table().select("icao", "lat", "lon").iter_rows()}


def _positions(icao: pl.Series) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lon) of each airport, NaN for a code that is not one (UNKNOWN)."""
    known = _airport_positions()
    return np.array([known.get(c, (np.nan, np.nan)) for c in icao], dtype=float).reshape(-1, 2).T


def _unit_xyz(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """Points on the unit sphere: great-circle neighbourhoods become Euclidean balls (radius 2 sin(θ/2)),
    which a k-d tree searches ~10x faster than a haversine ball tree."""
    la, lo = np.radians(lat), np.radians(lon)
    return np.c_[np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]


@lru_cache(maxsize=2)
def _tree(ils_only: bool) -> tuple[cKDTree, pl.DataFrame]:
    ap = airports_table().filter(pl.col("ils")) if ils_only else airports_table()
    return cKDTree(_unit_xyz(ap["lat"].to_numpy(), ap["lon"].to_numpy())), ap


def _bearing_deg(lat1, lon1, lat2, lon2):
    p1, p2, dl = np.radians(lat1), np.radians(lat2), np.radians(lon2 - lon1)
    y = np.sin(dl) * np.cos(p2)
    x = np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl)
    return np.degrees(np.arctan2(y, x)) % 360


def best_airport(lat: np.ndarray, lon: np.ndarray, alt_m: np.ndarray, heading_deg: np.ndarray):
    """Per point: (icao, distance_nm) of the airport best explaining a flight heading there from this point."""
    icao, dist = _best_among(lat, lon, alt_m, heading_deg, ils_only=True)
    missing = np.isnan(dist)
    if missing.any():
        icao[missing], dist[missing] = _best_among(lat[missing], lon[missing], alt_m[missing], heading_deg[missing], ils_only=False)
    return icao, dist


def _best_among(lat, lon, alt_m, heading_deg, ils_only: bool):
    tree, ap = _tree(ils_only)
    ap_lat, ap_lon, icao = ap["lat"].to_numpy(), ap["lon"].to_numpy(), ap["icao"].to_numpy()
    # every (point, airport) pair within the search radius, as flat arrays, in one tree-against-tree pass
    pairs = cKDTree(_unit_xyz(lat, lon)).sparse_distance_matrix(
        tree, 2 * np.sin(SEARCH_RADIUS_NM / EARTH_RADIUS_NM / 2), output_type="ndarray"
    )
    owner, cand = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
    d_nm = 2 * np.arcsin(np.minimum(pairs["v"] / 2, 1.0)) * EARTH_RADIUS_NM
    off = np.radians((_bearing_deg(lat[owner], lon[owner], ap_lat[cand], ap_lon[cand]) - heading_deg[owner] + 180) % 360 - 180)
    to_go = np.clip(alt_m[owner] / M_PER_FT, 0, None) / FT_PER_NM_PATH
    score = np.abs(d_nm * np.sin(off)) + 0.25 * np.abs(d_nm * np.cos(off) - to_go)
    score[np.abs(np.degrees(off)) > MAX_OFF_TRACK_DEG] = np.inf
    terminal = to_go < TERMINAL_AREA_NM
    score[terminal] = d_nm[terminal]
    best_icao = np.full(len(lat), None, dtype=object)
    best_dist = np.full(len(lat), np.nan)
    if len(cand):
        order = np.lexsort((score, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        ok = np.isfinite(score[first])
        best_icao[owner[first][ok]] = icao[cand[first][ok]]
        best_dist[owner[first][ok]] = d_nm[first][ok]
    return best_icao, best_dist


def _distance_nm(lat1, lon1, lat2, lon2):
    p1, p2 = np.radians(lat1), np.radians(lat2)
    a = np.sin((p2 - p1) / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(np.radians(lon2 - lon1) / 2) ** 2
    return 2 * EARTH_RADIUS_NM * np.arcsin(np.sqrt(a))


def flights_table(tracks: pl.DataFrame) -> pl.DataFrame:
    """One row per flight with origin/destination (and the distance to them) from its end points."""
    src = in_flight_order(tracks)
    # flights are contiguous runs of rows: their end points are gathered by position, no grouping needed
    start = run_starts(src["flight_id"])
    end = run_ends(start, src.height) - 1
    lat, lon, alt = (src[c].to_numpy() for c in ("lat", "lon", "alt_m"))
    ends = src.select("flight_id", "callsign", "icao24", first_ts="ts")[start].with_columns(
        last_ts=src["ts"].gather(end), n_points=pl.Series(end - start + 1, dtype=pl.Int64),
    )
    # both ends of every flight in one airport search: the first points looking back from 10 points in, the last
    # ones looking ahead from 10 points before (no heading on shorter flights): reported track can be missing at the ends
    long = np.tile(end - start >= 10, 2)
    at, inner = np.r_[start, end], np.where(long, np.r_[start + 10, end - 10], 0)
    lat_at, lon_at = lat[at], lon[at]
    heading = _bearing_deg(np.where(long, lat[inner], np.nan), np.where(long, lon[inner], np.nan), lat_at, lon_at)
    airport, _ = best_airport(lat_at, lon_at, alt[at], heading)
    origin, dest = airport[: len(start)], airport[len(start) :]
    # lists, not the object arrays: polars cannot cast an object array that starts with None (no airport) to String
    voted = ends.with_columns(origin=pl.Series(origin.tolist(), dtype=pl.String), destination=pl.Series(dest.tolist(), dtype=pl.String))
    voted = voted.with_columns(
        pl.col(c).drop_nulls().mode().sort().first().over("callsign").fill_null(pl.col(c)).fill_null("UNKNOWN")
        for c in ("origin", "destination")
    )
    # the voted airports' positions looked up for both ends (a join with the 13,795 airports cost ~1.5 ms)
    ap_lat, ap_lon = _positions(pl.concat([voted["origin"], voted["destination"]]))
    distance = _distance_nm(lat_at, lon_at, ap_lat, ap_lon)
    return voted.with_columns(
        route=pl.concat_str("origin", "destination", separator="-"),
        origin_distance_nm=pl.Series(distance[: len(start)]),
        destination_distance_nm=pl.Series(distance[len(start) :]),
    ).select(
        "flight_id", "callsign", "icao24", "origin", "destination", "route", "origin_distance_nm",
        "destination_distance_nm", "first_ts", "last_ts", "n_points",
    ).sort("flight_id")
