"""Flight-track ingest: read state vectors, clean them, split them into flights, account for every row.

Two input schemas are recognised from their column names (units follow from the schema, see README):

* OpenSky state vectors (Impala `state_vectors_data4`): time, icao24, lat, lon, baroaltitude [m],
  velocity [m/s], heading [deg], vertrate [m/s], callsign, onground, lastposupdate [epoch s].
* `traffic`-style tables: timestamp, icao24, latitude, longitude, altitude [ft], groundspeed [kt],
  track [deg], vertical_rate [ft/min], callsign.

Every row read ends either in the cleaned tracks or in the rejects with one reason, so
kept + rejected = read always holds (`ingest_summary`).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

FT = 0.3048
KT = 1852.0 / 3600.0
FPM = FT / 60.0
TS_DTYPE = pl.Datetime("us", "UTC")


class IngestError(ValueError):
    """Input that cannot be ingested at all (wrong path, format, schema or unit). One line."""


@dataclass(frozen=True)
class Schema:
    name: str
    columns: dict[str, str]  # canonical name -> source column
    scale: dict[str, float]  # canonical name -> factor to SI
    optional: frozenset[str]


OPENSKY = Schema(
    "opensky",
    {
        "ts": "time",
        "icao24": "icao24",
        "callsign": "callsign",
        "lat": "lat",
        "lon": "lon",
        "alt_m": "baroaltitude",
        "groundspeed_mps": "velocity",
        "track_deg": "heading",
        "vertical_rate_mps": "vertrate",
        "onground": "onground",
        "pos_time": "lastposupdate",
    },
    {"alt_m": 1.0, "groundspeed_mps": 1.0, "vertical_rate_mps": 1.0},
    frozenset({"callsign", "groundspeed_mps", "track_deg", "vertical_rate_mps", "onground", "pos_time"}),
)
TRAFFIC = Schema(
    "traffic",
    {
        "ts": "timestamp",
        "icao24": "icao24",
        "callsign": "callsign",
        "lat": "latitude",
        "lon": "longitude",
        "alt_m": "altitude",
        "groundspeed_mps": "groundspeed",
        "track_deg": "track",
        "vertical_rate_mps": "vertical_rate",
        "onground": "onground",
        "pos_time": "last_position",
    },
    {"alt_m": FT, "groundspeed_mps": KT, "vertical_rate_mps": FPM},
    frozenset({"callsign", "groundspeed_mps", "track_deg", "vertical_rate_mps", "onground", "pos_time"}),
)
SCHEMAS = (OPENSKY, TRAFFIC)
CANONICAL = list(OPENSKY.columns)


@dataclass(frozen=True)
class IngestConfig:
    """Cleaning thresholds. Defaults suit airliner tracks at 1-10 s resolution."""

    gap_split_s: float = 1800.0  # a longer silence starts a new flight (OpenSky has 15-min holes mid-flight)
    min_points: int = 60  # received positions a flight needs to be kept
    min_alt_m: float = -500.0
    max_alt_m: float = 15500.0  # above any airliner's ceiling: a decoding error
    max_speed_mps: float = 350.0  # implied ground speed between positions, both sides of a spike
    max_climb_mps: float = 100.0  # implied vertical speed between positions, both sides of a spike


# --------------------------------------------------------------------------------------------- reading


def read_source(path: str | Path) -> pl.DataFrame:
    """Read a Parquet, CSV or JSON (records, optionally gzip) file of state vectors."""
    p = Path(path)
    if not p.exists():
        raise IngestError(f"{p}: no such file")
    if p.is_dir():
        raise IngestError(f"{p}: is a folder, expected a Parquet, CSV or JSON file")
    suffixes = [s.lower() for s in p.suffixes[-2:]]
    kind = suffixes[-2] if suffixes[-1:] == [".gz"] and len(suffixes) == 2 else suffixes[-1] if suffixes else ""
    try:
        if kind in (".parquet", ".pq"):
            df = pl.read_parquet(p)
        elif kind in (".csv", ".tsv"):
            df = pl.read_csv(
                p, separator="\t" if kind == ".tsv" else ",", infer_schema_length=10000,
                schema_overrides={c: pl.String for c in ("icao24", "callsign", "squawk")},
            )
        elif kind in (".json", ".jsonl", ".ndjson"):
            df = _read_json(p, lines=kind != ".json")
        else:
            raise IngestError(f"{p}: unsupported file type '{kind or p.name}', expected .parquet, .csv or .json")
    except IngestError:
        raise
    except Exception as e:  # polars/arrow raise many types for a corrupt file; the user needs one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise IngestError(f"{p}: not a readable {kind.lstrip('.')} file ({first})") from None
    if df.height == 0:
        raise IngestError(f"{p}: the file has no rows")
    return df


def _read_json(p: Path, lines: bool) -> pl.DataFrame:
    import gzip
    import io

    raw = gzip.open(p).read() if p.suffix.lower() == ".gz" else p.read_bytes()
    return pl.read_ndjson(io.BytesIO(raw)) if lines else pl.read_json(io.BytesIO(raw))


# --------------------------------------------------------------------------------------------- schema


def detect_schema(columns: list[str], source: str = "input") -> Schema:
    present = set(columns)
    for schema in SCHEMAS:
        required = {c for k, c in schema.columns.items() if k not in schema.optional}
        if required <= present:
            return schema
    best = max(SCHEMAS, key=lambda s: len(set(s.columns.values()) & present))
    missing = sorted({c for k, c in best.columns.items() if k not in best.optional} - present)
    raise IngestError(
        f"{source}: missing columns {missing} for the {best.name} schema "
        f"(found: {', '.join(sorted(present)[:12])}{'…' if len(present) > 12 else ''})"
    )


def _timestamps(col: pl.Series, source: str) -> pl.Series:
    """Datetime, ISO string, or epoch seconds / milliseconds (told apart by magnitude) -> UTC datetime."""
    if col.dtype == pl.String:
        parsed = col.str.to_datetime(time_zone="UTC", strict=False)
        if parsed.null_count() > col.null_count():
            raise IngestError(f"{source}: column '{col.name}' has values that are not timestamps")
        return parsed.cast(TS_DTYPE)
    if isinstance(col.dtype, pl.Datetime):
        if col.dtype.time_zone is None:
            col = col.dt.replace_time_zone("UTC")
        return col.dt.convert_time_zone("UTC").cast(TS_DTYPE)
    if col.dtype.is_numeric():
        med = col.cast(pl.Float64).drop_nans().median()
        factor = 1_000 if med is not None and med > 1e11 else 1_000_000  # epoch ms vs epoch s
        return (col.cast(pl.Float64) * factor).round().cast(pl.Int64).cast(TS_DTYPE)
    raise IngestError(f"{source}: column '{col.name}' has type {col.dtype}, expected timestamps")


def normalise(df: pl.DataFrame, source: str) -> pl.DataFrame:
    """Rename to canonical columns, convert to SI units, add row_index. Raises IngestError on wrong units."""
    schema = detect_schema(df.columns, source)
    out = {"row_index": pl.Series("row_index", np.arange(df.height, dtype=np.int64))}
    for canon, col in schema.columns.items():
        if col not in df.columns:
            out[canon] = pl.repeat(None, df.height, eager=True).alias(canon)
            continue
        s = df[col]
        if canon == "ts":
            s = _timestamps(s, source)
        elif canon in ("icao24", "callsign"):
            s = s.cast(pl.String).str.strip_chars()
            s = s.str.to_lowercase() if canon == "icao24" else s.replace("", None)
        elif canon == "onground":
            s = s.cast(pl.Boolean, strict=False)
        elif canon == "pos_time":
            s = _timestamps(s, source).dt.epoch("us") if s.dtype != pl.Float64 else (s * 1e6).round()
            s = s.cast(pl.Float64)
        else:
            if not s.dtype.is_numeric():
                raise IngestError(f"{source}: column '{col}' is {s.dtype}, expected numbers")
            s = s.cast(pl.Float64).fill_nan(None) * schema.scale.get(canon, 1.0)
        out[canon] = s.alias(canon)
    frame = pl.DataFrame(out).with_columns(pl.col("onground").cast(pl.Boolean), pl.col("pos_time").cast(pl.Float64))
    check_units(frame, schema, source)
    return frame


def check_units(df: pl.DataFrame, schema: Schema, source: str) -> None:
    """Catch the common unit mix-ups (feet in a metres column and vice versa) from airborne medians."""
    air = df.filter(pl.col("alt_m") > 0)
    if air.height == 0:
        return
    alt_col = schema.columns["alt_m"]
    p95_alt = air["alt_m"].quantile(0.95)
    if p95_alt is not None and p95_alt > 16_000:
        raise IngestError(
            f"{source}: '{alt_col}' reaches {p95_alt:,.0f} m at the 95th percentile: it looks like feet, "
            f"but the {schema.name} schema reads it as {'metres' if schema.scale['alt_m'] == 1 else 'feet'}"
        )
    gs = air["groundspeed_mps"].drop_nulls()
    if gs.len():
        med = gs.median()
        if med > 400:
            raise IngestError(
                f"{source}: '{schema.columns['groundspeed_mps']}' has a median of {med:,.0f} m/s after conversion: "
                f"wrong unit for the {schema.name} schema"
            )
    if schema is TRAFFIC and p95_alt is not None and p95_alt < 4_000 * FT and (gs.median() or 0) > 150:
        raise IngestError(
            f"{source}: 'altitude' stays below 4,000 while flying at airliner speed: it looks like metres or "
            "flight levels, but the traffic schema reads it as feet"
        )


# --------------------------------------------------------------------------------------------- cleaning


def _haversine_m(lat1, lon1, lat2, lon2) -> pl.Expr:
    r = 6_371_000.0
    dlat = (lat2 - lat1).radians()
    dlon = (lon2 - lon1).radians()
    a = (dlat / 2).sin() ** 2 + lat1.radians().cos() * lat2.radians().cos() * (dlon / 2).sin() ** 2
    return 2 * r * a.sqrt().arcsin()


def _spike(prev: str, nxt: str) -> pl.Expr:
    """An isolated point the aircraft could not have reached and left again (both legs impossible)."""
    return pl.col(prev).fill_null(0.0) & pl.col(nxt).fill_null(0.0)


def _speed_spike(cfg: IngestConfig) -> pl.Expr:
    by = "icao24"
    dt_prev = (pl.col("ts") - pl.col("ts").shift(1).over(by)).dt.total_microseconds() / 1e6
    dt_next = (pl.col("ts").shift(-1).over(by) - pl.col("ts")).dt.total_microseconds() / 1e6
    d_prev = _haversine_m(pl.col("lat"), pl.col("lon"), pl.col("lat").shift(1).over(by), pl.col("lon").shift(1).over(by))
    d_next = _haversine_m(pl.col("lat"), pl.col("lon"), pl.col("lat").shift(-1).over(by), pl.col("lon").shift(-1).over(by))
    h_prev = (pl.col("alt_m") - pl.col("alt_m").shift(1).over(by)).abs()
    h_next = (pl.col("alt_m").shift(-1).over(by) - pl.col("alt_m")).abs()
    # 1 s floor on dt: OpenSky timestamps are whole seconds, a 0 s step would make every move "infinite"
    fast = lambda d, dt, lim: (d / dt.clip(lower_bound=1.0)) > lim  # noqa: E731
    return (fast(d_prev, dt_prev, cfg.max_speed_mps) & fast(d_next, dt_next, cfg.max_speed_mps)).fill_null(False) | (
        fast(h_prev, dt_prev, cfg.max_climb_mps) & fast(h_next, dt_next, cfg.max_climb_mps)
    ).fill_null(False)


def _row_rules(cfg: IngestConfig) -> list[tuple[str, pl.Expr]]:
    """(reason, expression true for rows to reject), applied in order to the rows still kept."""
    by = "icao24"
    return [
        ("missing_value", pl.any_horizontal(pl.col("ts", "icao24", "lat", "lon", "alt_m").is_null())),
        ("duplicate_row", pl.struct("icao24", "ts").is_duplicated() & ~pl.struct("icao24", "ts").is_first_distinct()),
        ("on_ground", pl.col("onground").fill_null(False)),
        (
            "out_of_range",
            ~pl.col("lat").is_between(-90, 90)
            | ~pl.col("lon").is_between(-180, 180)
            | ~pl.col("alt_m").is_between(cfg.min_alt_m, cfg.max_alt_m)
            | (pl.col("groundspeed_mps").fill_null(0) > 2 * cfg.max_speed_mps),
        ),
        # OpenSky repeats the last position until a new one arrives: keep only received positions
        (
            "repeated_position",
            pl.when(pl.col("pos_time").is_not_null())
            .then(pl.col("pos_time") == pl.col("pos_time").shift(1).over(by))
            .otherwise((pl.col("lat") == pl.col("lat").shift(1).over(by)) & (pl.col("lon") == pl.col("lon").shift(1).over(by)))
            .fill_null(False),
        ),
        ("speed_spike", _speed_spike(cfg)),
    ]


def _split_flights(kept: pl.DataFrame, cfg: IngestConfig) -> pl.DataFrame:
    gap = (pl.col("ts") - pl.col("ts").shift(1).over("icao24")).dt.total_seconds(fractional=True)
    callsign_changed = (pl.col("callsign") != pl.col("callsign").shift(1).over("icao24")).fill_null(False)
    new = (gap.is_null() | (gap > cfg.gap_split_s) | callsign_changed).cast(pl.Int64)
    return (
        kept.with_columns(pl.col("callsign").fill_null(strategy="forward").over("icao24"))
        .with_columns(segment=new.cum_sum())
        .with_columns(
            flight_id=pl.concat_str(
                pl.col("callsign").fill_null(pl.col("icao24")).first().over("segment"),
                pl.col("icao24"),
                pl.col("ts").first().over("segment").dt.strftime("%Y%m%dT%H%M"),
                separator="_",
            )
        )
    )


def clean(raw: pl.DataFrame, source: str, cfg: IngestConfig = IngestConfig()) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Normalised rows -> (cleaned points with flight_id, rejects with reason). Every row ends in one."""
    kept = raw.sort("icao24", "ts", "row_index", nulls_last=True)
    rejected = []
    for reason, rule in _row_rules(cfg):
        kept = kept.with_columns(_bad=rule)
        rejected.append(kept.filter("_bad").with_columns(reason=pl.lit(reason)))
        kept = kept.filter(~pl.col("_bad"))
    kept = _split_flights(kept.drop("_bad"), cfg)
    short = pl.len().over("flight_id") < cfg.min_points
    rejected.append(kept.filter(short).with_columns(reason=pl.lit("short_segment")))
    kept = kept.filter(~short).drop("segment")
    rejects = pl.concat(
        [r.select("row_index", "reason", "icao24", "callsign", "ts", "lat", "lon", "alt_m") for r in rejected]
    ).with_columns(source=pl.lit(source))
    tracks = kept.select(
        "flight_id", "ts", "icao24", "callsign", "lat", "lon", "alt_m", "groundspeed_mps", "track_deg", "vertical_rate_mps"
    )
    # a flight without a callsign keeps the icao24 as its callsign so that downstream keys are never null
    tracks = tracks.with_columns(pl.col("callsign").fill_null(pl.col("icao24")))
    return tracks.sort("flight_id", "ts"), rejects.sort("row_index")


def summarise(source: str, n_read: int, kept: int, rejects: pl.DataFrame) -> pl.DataFrame:
    """Row accounting: read = kept + sum(rejected per reason)."""
    per_reason = rejects.group_by("reason").agg(rows=pl.len().cast(pl.Int64)).sort("reason")
    head = pl.DataFrame(
        {"source": [source] * 2, "outcome": ["read", "kept"], "reason": ["", ""], "rows": [n_read, kept]},
        schema={"source": pl.String, "outcome": pl.String, "reason": pl.String, "rows": pl.Int64},
    )
    rej = per_reason.select(source=pl.lit(source), outcome=pl.lit("rejected"), reason="reason", rows="rows")
    return pl.concat([head, rej])


def ingest(path: str | Path, cfg: IngestConfig = IngestConfig()) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """Read one file -> (cleaned tracks, rejects, summary). Raises IngestError on unusable input."""
    source = Path(path).name
    raw = normalise(read_source(path), source)
    tracks, rejects = clean(raw, source, cfg)
    summary = summarise(source, raw.height, tracks.height, rejects)
    assert tracks.height + rejects.height == raw.height, "row accounting broken"
    return tracks, rejects, summary
