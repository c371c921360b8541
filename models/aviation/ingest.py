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
UNIT_SAMPLE_ROWS = 50_000
TS_DTYPE = pl.Datetime("us", "UTC")


class IngestError(ValueError):
    """Input that cannot be ingested at all (wrong path, format, schema or unit). One line."""


@dataclass(frozen=True)
class Schema:
    name: str
    columns: dict[str, str]  # canonical name -> source column
    scale: dict[str, float]  # canonical name -> factor to SI
    optional: frozenset[str]

    @property
    def required(self) -> set[str]:
        """Source columns a file must have."""
        return {c for k, c in self.columns.items() if k not in self.optional}


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
TRACK_COLUMNS = ("row_index", "_ac", "ts", "lat", "lon", "alt_m")  # what the slim frame passes on to the tracks


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
            df = pl.read_parquet(p, columns=_used_columns(list(pl.read_parquet_schema(p))))
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


def _used_columns(present: list[str]) -> list[str]:
    """The columns ingest uses, in file order, when a schema matches (OpenSky exports carry ~10 more);
    all of them otherwise, so that `detect_schema` can say what is missing."""
    for schema in SCHEMAS:
        if schema.required <= set(present):
            return [c for c in present if c in schema.columns.values()]
    return present


def _read_json(p: Path, lines: bool) -> pl.DataFrame:
    import gzip
    import io

    raw = gzip.open(p).read() if p.suffix.lower() == ".gz" else p.read_bytes()
    return pl.read_ndjson(io.BytesIO(raw)) if lines else pl.read_json(io.BytesIO(raw))


# --------------------------------------------------------------------------------------------- schema


def detect_schema(columns: list[str], source: str = "input") -> Schema:
    present = set(columns)
    for schema in SCHEMAS:
        if schema.required <= present:
            return schema
    best = max(SCHEMAS, key=lambda s: len(set(s.columns.values()) & present))
    missing = sorted(best.required - present)
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


def _tidy_names(names: pl.Series, lower: bool) -> pl.Series:
    """Strip (and lowercase) names, "" -> null (a blank icao24 is a missing one). Done on the distinct values (a few thousand aircraft among
    millions of rows, ~5x cheaper), and not at all when they are already tidy."""
    distinct = names.unique().drop_nulls()
    tidy = distinct.str.strip_chars()
    tidy = (tidy.str.to_lowercase() if lower else tidy).replace("", None)
    return names if tidy.equals(distinct) else names.replace_strict(distinct, tidy, default=None)


def normalise(df: pl.DataFrame, source: str) -> pl.DataFrame:
    """Rename to canonical columns, convert to SI units, add row_index. Raises IngestError on wrong units."""
    schema = detect_schema(df.columns, source)
    # timestamps are parsed and checked eagerly; the other columns are one select, which polars runs in parallel
    exprs = [pl.int_range(pl.len(), dtype=pl.Int64).alias("row_index")]
    for canon, col in schema.columns.items():
        if col not in df.columns:
            dtype = {"callsign": pl.String, "onground": pl.Boolean}.get(canon, pl.Float64)
            exprs.append(pl.lit(None, dtype=dtype).alias(canon))
            continue
        e = pl.col(col)
        if canon == "ts":
            e = pl.lit(_timestamps(df[col], source))
        elif canon in ("icao24", "callsign"):
            e = pl.lit(_tidy_names(df[col].cast(pl.String), lower=canon == "icao24"))
        elif canon == "onground":
            e = e.cast(pl.Boolean, strict=False)
        elif canon == "pos_time":  # epoch seconds as they come, else timestamps: both to epoch µs
            e = (e * 1e6).round() if df[col].dtype == pl.Float64 else pl.lit(_timestamps(df[col], source).dt.epoch("us").cast(pl.Float64))
        else:
            if not df[col].dtype.is_numeric():
                raise IngestError(f"{source}: column '{col}' is {df[col].dtype}, expected numbers")
            e = e.cast(pl.Float64).fill_nan(None)
            e = e * schema.scale[canon] if schema.scale.get(canon, 1.0) != 1.0 else e
        exprs.append(e.alias(canon))
    frame = df.select(exprs)
    check_units(frame, schema, source)
    return frame


def check_units(df: pl.DataFrame, schema: Schema, source: str) -> None:
    """Catch the common unit mix-ups (feet in a metres column and vice versa) from airborne medians.

    Percentiles of an evenly spaced sample of ≤ 50,000 rows: they move by metres, the thresholds are kilometres apart."""
    air = df.select("alt_m", "groundspeed_mps").gather_every(max(1, df.height // UNIT_SAMPLE_ROWS)).filter(pl.col("alt_m") > 0)
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


def _leg_m(lat1, lon1, lat2, lon2) -> pl.Expr:
    """Equirectangular distance: within 0.5 % of great-circle for legs under 500 km, at a third of
    haversine's cost, which is plenty for an impossible-speed test."""
    r = 6_371_000.0
    dlon = ((lon2 - lon1 + 180.0) % 360.0 - 180.0).radians() * ((lat1 + lat2) / 2).radians().cos()
    return r * ((lat2 - lat1).radians() ** 2 + dlon**2).sqrt()


def _prev(c: str) -> pl.Expr:
    """Value of the previous row of the same aircraft (rows sorted by aircraft, `_ac` = aircraft id).

    A shift guarded by the aircraft id is the same as `shift(1).over("icao24")` on sorted rows, without a window."""
    return pl.when(pl.col("_ac") == pl.col("_ac").shift(1)).then(pl.col(c).shift(1))


def _speed_spike(cfg: IngestConfig) -> pl.Expr:
    """An isolated point the aircraft could not have reached and left again (both legs impossible).

    Each leg is computed once, as the leg from the previous row, and only counts within one aircraft; the
    leg to the next point is the next row's."""
    same = (pl.col("_ac") == pl.col("_ac").shift(1)).fill_null(False)
    # 1 s floor on dt: OpenSky timestamps are whole seconds, a 0 s step would make every move "infinite"
    dt_in = ((pl.col("ts") - pl.col("ts").shift(1)).dt.total_microseconds() / 1e6).clip(lower_bound=1.0)
    leg_in = _leg_m(pl.col("lat").shift(1), pl.col("lon").shift(1), pl.col("lat"), pl.col("lon"))
    too_fast = same & (leg_in / dt_in > cfg.max_speed_mps)
    too_steep = same & ((pl.col("alt_m") - pl.col("alt_m").shift(1)).abs() / dt_in > cfg.max_climb_mps)
    spike = lambda leg: (leg & leg.shift(-1)).fill_null(False)  # noqa: E731
    return spike(too_fast) | spike(too_steep)


def _row_rules(cfg: IngestConfig) -> list[list[tuple[str, pl.Expr]]]:
    """Stages of (reason, expression true for rows to reject). Within a stage the first matching reason
    wins and all rules see the same rows; a stage sees only the rows the previous stages kept. The first
    stage must test each row alone (it runs before the rows are sorted).

    Rows are sorted by (aircraft, ts, row_index), so a duplicate is a row equal to its predecessor and the
    first of the duplicates (lowest row_index) is the one kept."""
    return [
        [("missing_value", pl.any_horizontal(pl.col("ts", "_ac", "lat", "lon", "alt_m").is_null()))],
        [
            ("duplicate_row", (pl.col("ts") == _prev("ts")).fill_null(False)),
            ("on_ground", pl.col("onground").fill_null(False)),
            (
                "out_of_range",
                ~pl.col("lat").is_between(-90, 90)
                | ~pl.col("lon").is_between(-180, 180)
                | ~pl.col("alt_m").is_between(cfg.min_alt_m, cfg.max_alt_m)
                | (pl.col("groundspeed_mps").fill_null(0) > 2 * cfg.max_speed_mps),
            ),
        ],
        # OpenSky repeats the last position until a new one arrives: keep only received positions
        [
            (
                "repeated_position",
                pl.when(pl.col("pos_time").is_not_null())
                .then(pl.col("pos_time") == _prev("pos_time"))
                .otherwise((pl.col("lat") == _prev("lat")) & (pl.col("lon") == _prev("lon")))
                .fill_null(False),
            )
        ],
        [("speed_spike", _speed_spike(cfg))],
    ]


def _split_flights(kept: pl.DataFrame, icao24: pl.Series, cfg: IngestConfig) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Number the flights (a new one at an aircraft's first point, after a long gap or a callsign change)
    and name them callsign_icao24_YYYYMMDDTHHMM from their first point; names are built once per flight.

    Returns (kept with `segment`, 0-based flight number, and the callsign filled forward per aircraft;
    one row per flight: flight_id, flight_rank = rank of the name, points). `icao24` is the raw column."""
    if kept["callsign"].null_count():  # a window per aircraft, only when some callsign is missing
        kept = kept.with_columns(pl.col("callsign").fill_null(strategy="forward").over("_ac"))
    gap = (pl.col("ts") - _prev("ts")).dt.total_seconds(fractional=True)
    callsign_changed = (pl.col("callsign") != _prev("callsign")).fill_null(False)
    new = gap.is_null() | (gap > cfg.gap_split_s) | callsign_changed
    kept = kept.with_columns(_new=new).with_columns(segment=pl.col("_new").cum_sum() - 1)
    firsts = kept.filter("_new")
    first_icao24 = icao24.gather(firsts["row_index"])
    flights = firsts.select(
        flight_id=pl.concat_str(
            pl.col("callsign").fill_null(first_icao24), pl.lit(first_icao24), pl.col("ts").dt.strftime("%Y%m%dT%H%M"), separator="_"
        ),
        points=pl.Series(np.bincount(kept["segment"].to_numpy(), minlength=firsts.height), dtype=pl.Int64),
    )
    # the rank of the name lets the final sort by (flight_id, ts) compare integers instead of strings
    return kept.drop("_new"), flights.with_columns(flight_rank=pl.col("flight_id").rank("dense"))


def _aircraft_ids(icao24: pl.Series) -> pl.Series:
    """An integer per aircraft that sorts like icao24: the 24-bit address itself when every value is six hex
    digits (as ICAO addresses are), else the dense rank of the string (sorting strings costs 2-3x more)."""
    hex_id = icao24.str.to_integer(base=16, strict=False)
    six_digits = (icao24.str.len_bytes() == 6) & ~icao24.str.starts_with("+") & ~icao24.str.starts_with("-")
    if hex_id.null_count() == icao24.null_count() and six_digits.all(ignore_nulls=True):
        return hex_id.alias("_ac")
    return icao24.rank("dense").cast(pl.Int64).alias("_ac")


def _aircraft_time_order(rows: pl.DataFrame, among: np.ndarray) -> np.ndarray:
    """Positions of the rows `among` (no null ts or aircraft) in (aircraft, ts, row_index) order: two stable
    numpy sorts of integer keys (timsort finds the runs of a presorted file) and no column moved until the
    one gather, ~2x cheaper than polars sorting the frame."""
    ts = rows["ts"].dt.epoch("us").to_numpy()[among]
    order = np.argsort(ts, kind="stable")
    order = order[np.argsort(rows["_ac"].to_numpy()[among][order], kind="stable")]
    return among[order]


def _tested(stage: list[tuple[str, pl.Expr]]) -> set[str]:
    """Columns the rules of a stage read."""
    return {c for _, rule in stage for c in rule.meta.root_names()}


def _first_match(frame: pl.DataFrame, stage: list[tuple[str, pl.Expr]]) -> tuple[pl.Series, pl.DataFrame]:
    """(rows hit by a rule of the stage, their row_index and reason: the first rule that matches)."""
    # the rule as a small integer: a string per row would cost more than the rules themselves
    rule_no = frame.select(pl.coalesce(pl.when(rule).then(pl.lit(j, pl.UInt8)) for j, (_, rule) in enumerate(stage))).to_series()
    hit = rule_no.is_not_null()
    reason = pl.Series("reason", [name for name, _ in stage]).gather(rule_no.filter(hit))
    return hit, pl.DataFrame([frame["row_index"].filter(hit), reason])


def clean(raw: pl.DataFrame, source: str, cfg: IngestConfig = IngestConfig()) -> tuple[pl.DataFrame, pl.DataFrame]:
    """Normalised rows (`normalise`'s output: row_index is the row's position) -> (cleaned points with
    flight_id, rejects with reason). Every row ends in one.

    The rules run on a slim frame of the numbers they test, sorted by (aircraft, ts, row_index); the strings
    and the other columns are gathered once, for the rows that survive, in their final order (and for the
    rejects, in theirs)."""
    missing, *stages = _row_rules(cfg)
    # the slim frame: the columns the rules test and those the tracks take from it
    slim = set(TRACK_COLUMNS).union(*map(_tested, [missing, *stages]))
    rows = raw.with_columns(_aircraft_ids(raw["icao24"])).select(c for c in dict.fromkeys([*TRACK_COLUMNS, *raw.columns]) if c in slim)
    # the first stage looks at each row alone, so it runs before the sort, which then orders only the rows left
    hit, rejects = _first_match(rows, missing)
    rejected = [rejects]
    kept = rows[_aircraft_time_order(rows, np.flatnonzero(~hit.to_numpy()))]
    for i, stage in enumerate(stages):
        hit, rejects = _first_match(kept, stage)
        # carry on only with the columns that the later stages and the tracks use
        later = set(TRACK_COLUMNS).union(*map(_tested, stages[i + 1 :]))
        kept = kept.select(c for c in kept.columns if c in later)
        if rejects.height:  # a filter copies every column: skip it when the stage rejects nothing
            rejected.append(rejects)
            kept = kept.filter(~hit)
    kept = kept.with_columns(callsign=raw["callsign"].gather(kept["row_index"]))
    kept, flights = _split_flights(kept, raw["icao24"], cfg)
    # rows are in (aircraft, ts) order and a flight_id names one aircraft, so a stable sort on the flight's
    # rank alone gives (flight_id, ts) order at a sixth of the cost of sorting on both
    kept = kept.with_columns(flights.select("flight_rank", "points")[kept["segment"]]).sort("flight_rank", maintain_order=True)
    short = pl.col("points") < cfg.min_points
    rejected.append(kept.filter(short).select("row_index", reason=pl.lit("short_segment")))
    kept = kept.filter(~short)
    reasons = pl.concat(rejected).sort("row_index")
    rejects = pl.concat(
        [reasons, raw.select("icao24", "callsign", "ts", "lat", "lon", "alt_m")[reasons["row_index"]]], how="horizontal"
    ).with_columns(source=pl.lit(source))
    # the other columns are gathered once, in the final order
    more = raw.select("icao24", "groundspeed_mps", "track_deg", "vertical_rate_mps")[kept["row_index"]]
    tracks = pl.concat([kept, more, flights.select("flight_id")[kept["segment"]]], how="horizontal").select(
        "flight_id", "ts", "icao24",
        # a flight without a callsign keeps the icao24 as its callsign so that downstream keys are never null
        pl.col("callsign").fill_null(pl.col("icao24")),
        "lat", "lon", "alt_m", "groundspeed_mps", "track_deg", "vertical_rate_mps",
    )
    return tracks, rejects


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
