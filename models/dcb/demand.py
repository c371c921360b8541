"""Demand for the DCB system: flights as 4D points, from ADS-B tracks or EUROCONTROL SO6 flight plans.

Two sources give the same `points` frame (flight_id, ts, lat, lon, fl) plus one row per flight
(flight_id, callsign, aircraft_type):

* ADS-B / OpenSky / `traffic` tables go through the foundation's ingest (`models.aviation.ingest`),
  which cleans them and accounts for every row (its rejects are reported by the DCB asset).
* SO6 (EUROCONTROL NEST/DDR "m1/m3" segment files): one line per flown segment, 20 space-separated
  fields; latitudes/longitudes in decimal minutes, times HHMMSS, dates YYMMDD, levels in FL.
  Lines that cannot be parsed are quarantined with their line number and reason (kept + rejected = read).
  Segments are densified to points every `step_s` seconds so that sector crossings inside a long
  segment are found.
"""

from pathlib import Path

import numpy as np
import polars as pl

from models.aviation.ingest import IngestConfig, ingest
from models.units import M_PER_FT

FT_PER_FL = 100.0
TS = pl.Datetime("us", "UTC")

SO6_FIELDS = (
    "segment_id", "origin", "destination", "aircraft_type", "time_begin", "time_end", "fl_begin", "fl_end",
    "status", "callsign", "date_begin", "date_end", "lat_begin_min", "lon_begin_min", "lat_end_min",
    "lon_end_min", "flight_key", "sequence", "length_nm", "parity",
)


class DemandError(ValueError):
    """A demand file that cannot be used at all (missing, empty, wrong format). One line."""


def adsb_demand(path: str | Path, min_points: int = 6) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """ADS-B tracks -> (points, flights, ingest rejects, ingest summary) through the foundation's ingest.

    `min_points` is low (6 received positions = 1 min at the Swiss sample's 10 s) because a flight
    that clips a corner of the airspace still counts as an entry."""
    tracks, rejects, summary = ingest(path, IngestConfig(min_points=min_points))
    points = tracks.select("flight_id", "ts", "lat", "lon", fl=pl.col("alt_m") / M_PER_FT / FT_PER_FL)
    flights = tracks.group_by("flight_id").agg(pl.col("callsign").first()).with_columns(
        aircraft_type=pl.lit(None, pl.String)  # ADS-B state vectors carry no aircraft type
    )
    return points, flights.sort("flight_id"), rejects, summary


def _so6_rejects(lines: pl.DataFrame, source: str, reason: pl.Expr) -> pl.DataFrame:
    return lines.filter(reason.is_not_null()).select(
        source=pl.lit(source), line_number=pl.col("line_number"), reason=reason, line=pl.col("line")
    )


def read_so6(path: str | Path) -> tuple[pl.DataFrame, pl.DataFrame]:
    """SO6 file -> (segments, rejects). Each line ends in exactly one of the two.

    Rejected reasons: wrong_field_count, bad_number, bad_time_or_date, time_reversed, out_of_range."""
    p = Path(path)
    if not p.is_file():
        raise DemandError(f"{p}: no such SO6 file")
    text = p.read_text(errors="replace")
    raw = text.splitlines()
    lines = pl.DataFrame({"line_number": np.arange(1, len(raw) + 1), "line": raw}, schema={"line_number": pl.Int64, "line": pl.String})
    lines = lines.filter(pl.col("line").str.strip_chars() != "")
    if lines.height == 0:
        raise DemandError(f"{p}: the SO6 file has no lines")
    source = p.name
    fields = pl.col("line").str.strip_chars().str.replace_all(r"\s+", " ").str.split(by=" ")  # spaces or tabs
    lines = lines.with_columns(_f=fields)
    wrong_count = pl.when(pl.col("_f").list.len() != len(SO6_FIELDS)).then(pl.lit("wrong_field_count"))
    rejected = [_so6_rejects(lines, source, wrong_count)]
    ok = lines.filter(pl.col("_f").list.len() == len(SO6_FIELDS)).with_columns(
        pl.col("_f").list.get(i).alias(name) for i, name in enumerate(SO6_FIELDS)
    )
    num = {c: pl.col(c).cast(pl.Float64, strict=False) for c in ("fl_begin", "fl_end", "lat_begin_min", "lon_begin_min", "lat_end_min", "lon_end_min")}
    # exactly YYMMDD and HHMMSS: a shorter time such as 0631 (HHMM) would otherwise parse as 00:06:31
    ts = {
        end: pl.when(pl.col(f"date_{end}").str.contains(r"^\d{6}$") & pl.col(f"time_{end}").str.contains(r"^\d{6}$"))
        .then(pl.col(f"date_{end}") + pl.col(f"time_{end}")).str.strptime(TS, "%y%m%d%H%M%S", strict=False)
        for end in ("begin", "end")
    }
    parsed = ok.with_columns(**num, t_begin=ts["begin"], t_end=ts["end"])
    reason = (
        pl.when(pl.any_horizontal(pl.col(c).is_null() for c in num)).then(pl.lit("bad_number"))
        .when(pl.col("t_begin").is_null() | pl.col("t_end").is_null()).then(pl.lit("bad_time_or_date"))
        .when(pl.col("t_end") < pl.col("t_begin")).then(pl.lit("time_reversed"))
        .when(
            ~pl.col("lat_begin_min").is_between(-5400, 5400) | ~pl.col("lat_end_min").is_between(-5400, 5400)
            | ~pl.col("lon_begin_min").is_between(-10800, 10800) | ~pl.col("lon_end_min").is_between(-10800, 10800)
            | ~pl.col("fl_begin").is_between(0, 999) | ~pl.col("fl_end").is_between(0, 999)
        ).then(pl.lit("out_of_range"))
    )
    rejected.append(_so6_rejects(parsed, source, reason))
    segments = parsed.filter(reason.is_null()).select(
        flight_id=pl.col("flight_key"), callsign="callsign", aircraft_type="aircraft_type",
        t_begin="t_begin", t_end="t_end",
        lat_begin=pl.col("lat_begin_min") / 60, lon_begin=pl.col("lon_begin_min") / 60,
        lat_end=pl.col("lat_end_min") / 60, lon_end=pl.col("lon_end_min") / 60,
        fl_begin="fl_begin", fl_end="fl_end", line_number="line_number",
    )
    rejects = pl.concat(rejected).sort("line_number")
    assert segments.height + rejects.height == lines.height, "SO6 line accounting broken"
    return segments.sort("flight_id", "t_begin"), rejects


def so6_demand(path: str | Path, step_s: float = 30.0) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """SO6 file -> (points, flights, rejects). Each segment becomes points every `step_s` (both ends kept)."""
    if not step_s > 0:
        raise DemandError(f"so6_step_s {step_s}: expected a positive step in seconds")
    segments, rejects = read_so6(path)
    if segments.height == 0:
        raise DemandError(f"{Path(path)}: no usable SO6 line ({rejects.height} rejected, see the quarantine)")
    dur_s = (segments["t_end"] - segments["t_begin"]).dt.total_seconds(fractional=True).to_numpy()
    n = np.maximum(np.ceil(dur_s / step_s), 1).astype(np.int64)  # sub-steps per segment
    seg = np.repeat(np.arange(segments.height), n + 1)
    frac = (np.arange(seg.size) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)) / np.repeat(n, n + 1)
    s = {c: segments[c].to_numpy()[seg] for c in ("lat_begin", "lat_end", "lon_begin", "lon_end", "fl_begin", "fl_end")}
    t0 = segments["t_begin"].to_numpy()[seg]
    points = pl.DataFrame({
        "flight_id": segments["flight_id"].to_numpy()[seg],
        "ts": t0 + (frac * dur_s[seg] * 1e6).astype("timedelta64[us]"),
        "lat": s["lat_begin"] + frac * (s["lat_end"] - s["lat_begin"]),
        "lon": s["lon_begin"] + frac * (s["lon_end"] - s["lon_begin"]),
        "fl": s["fl_begin"] + frac * (s["fl_end"] - s["fl_begin"]),
    }).with_columns(pl.col("ts").cast(TS)).unique(["flight_id", "ts"], keep="first", maintain_order=True)
    flights = segments.group_by("flight_id").agg(pl.col("callsign").first(), pl.col("aircraft_type").first())
    return points.sort("flight_id", "ts"), flights.sort("flight_id"), rejects
