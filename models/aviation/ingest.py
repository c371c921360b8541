"""Flight-track ingest: read state vectors, clean them, split them into flights, account for every row.

Two input schemas are recognised from their column names (units follow from the schema, see README):

* OpenSky state vectors (Impala `state_vectors_data4`): time, icao24, lat, lon, baroaltitude [m],
  velocity [m/s], heading [deg], vertrate [m/s], callsign, onground, lastposupdate [epoch s].
* `traffic`-style tables: timestamp, icao24, latitude, longitude, altitude [ft], groundspeed [kt],
  track [deg], vertical_rate [ft/min], callsign.

Every row read ends either in the cleaned tracks or in the rejects with one reason, so
kept + rejected = read always holds (`ingest_summary`).
"""

from bisect import bisect_right
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq

from models.aviation import kernels
from models.aviation.order import run_ends, runs
from models.aviation.resample import EARTH_RADIUS_M
from models.parallel import together
from models.units import M_PER_FT, MPS_PER_FPM, MPS_PER_KT

UNIT_SAMPLE_ROWS = 50_000
TS_DTYPE = pl.Datetime("us", "UTC")
MAX_MS = (2**63 - 1) // 1000  # the most milliseconds that are an int64 of µs
# a time outside these years is a decoding error; rejected before the sort, it cannot overflow the kernels' time
# differences nor a flight name's date (polars panics on a year past 262,143)
TS_RANGE_US = (0, 4_102_444_800_000_000)  # 1970-01-01 to 2100-01-01


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
    {"alt_m": M_PER_FT, "groundspeed_mps": MPS_PER_KT, "vertical_rate_mps": MPS_PER_FPM},
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
            df = _read_parquet(p)
        elif kind in (".csv", ".tsv"):
            df = pl.read_csv(
                p, separator="\t" if kind == ".tsv" else ",", infer_schema_length=10000,
                schema_overrides={c: pl.String for c in ("icao24", "callsign", "squawk")},
            )
        elif kind in (".json", ".jsonl", ".ndjson"):
            df = _read_json(p, lines=kind != ".json")
        else:
            raise IngestError(f"{p}: unsupported file type '{kind or p.name}', expected .parquet, .csv, .tsv, .json, .jsonl or .ndjson (the text ones may be gzipped: .csv.gz)")
    except IngestError:
        raise
    except Exception as e:  # polars/arrow raise many types for a corrupt file; the user needs one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise IngestError(f"{p}: not a readable {kind.lstrip('.')} file ({first})") from None
    if df.height == 0:
        raise IngestError(f"{p}: the file has no rows")
    return df


def _read_parquet(p: Path) -> pl.DataFrame:
    """The used columns, read in two halves of about equal stored bytes at once (one column's decoding is one thread's
    work in polars: 18.6 -> 10.8 ms for the bundled file on 2 cores)."""
    meta = pq.ParquetFile(p).metadata
    columns = _used_columns(meta.schema.to_arrow_schema().names)
    size = dict.fromkeys(columns, 0)
    for i in range(meta.num_columns):
        name = meta.schema.column(i).path.split(".")[0]  # a nested column's leaves count for it
        if name in size:
            size[name] += sum(meta.row_group(g).column(i).total_compressed_size for g in range(meta.num_row_groups))
    halves, stored = ([], []), [0, 0]
    for c in sorted(columns, key=size.get, reverse=True):
        half = int(stored[1] < stored[0])
        halves[half].append(c)
        stored[half] += size[c]
    parts = together(*(partial(pl.read_parquet, p, columns=h) for h in halves if h))
    return pl.concat(parts, how="horizontal").select(columns) if parts else pl.DataFrame()


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
        # the stored values are UTC instants in any zone (a naive column is read as UTC): only the unit changes, by
        # integer arithmetic that floors as polars' cast does (1.2 -> 0.4 ms on the bundled file's 528,432 rows); ms
        # beyond µs's int64 range (year ±292,000: a decoding error) are clipped first, else they would wrap into range
        unit, values = col.dtype.time_unit, col.to_physical()
        if unit == "ms":
            values = values.clip(-MAX_MS, MAX_MS) * 1000
        return (values // 1000 if unit == "ns" else values).cast(TS_DTYPE)
    if col.dtype.is_numeric():
        med = col.cast(pl.Float64).drop_nans().median()
        factor = 1_000 if med is not None and med > 1e11 else 1_000_000  # epoch ms vs epoch s
        return (col.cast(pl.Float64) * factor).round().cast(pl.Int64).cast(TS_DTYPE)
    raise IngestError(f"{source}: column '{col.name}' has type {col.dtype}, expected timestamps")


def _tidy_names(names: pl.Series, lower: bool) -> tuple[pl.Series, pl.Series]:
    """(names stripped (and lowercased), "" -> null (a blank icao24 is a missing one); a UInt32 code per row
    that sorts like the tidy name, null where it is null).

    Both come from the distinct names of the runs of equal rows: state vectors arrive in runs of one aircraft
    (the bundled file: 528,432 rows, 265 runs), and hashing a few hundred run values instead of every row is
    ~10x cheaper; the rows then take their run's code repeated by the runs' lengths (and their tidy name, where tidying
    changed one, in one gather by the run ids)."""
    run = names.rle_id()
    _, starts = runs(names, run)
    in_runs = len(starts) * 4 < len(names)  # else (e.g. rows sorted by time) the rows are their own values
    values = names.gather(starts) if in_runs else names
    distinct = values.unique().drop_nulls()
    tidy = distinct.str.strip_chars()
    tidy = (tidy.str.to_lowercase() if lower else tidy).replace("", None)
    # codes in sorted order of the tidy names: an integer key that orders (and groups) like the strings
    code = tidy.cast(pl.Enum(tidy.drop_nulls().unique().sort())).to_physical().cast(pl.UInt32)
    at = values.cast(pl.Enum(distinct)).to_physical()  # each value's position among the distinct ones
    code, tidied = code.gather(at), (None if tidy.equals(distinct) else tidy.gather(at))
    if in_runs:  # each run's code over its rows: repeated by the runs' lengths, ~10x cheaper than a gather by run id
        code = code.gather(run) if code.has_nulls() else pl.Series(np.repeat(code.to_numpy(), np.diff(starts, append=len(names))))
        tidied = None if tidied is None else tidied.gather(run)
    return (names if tidied is None else tidied), code


def _text_as_typed(col: pl.Series) -> pl.Series:
    """A text column whose every value is a number as numbers, or whose every value is true/false as booleans; else as
    it is. Polars reads a CSV column with no value in its first 10,000 rows as text (an export without vertical rates,
    altitudes or position times that start late)."""
    numbers = col.cast(pl.Float64, strict=False)
    if numbers.null_count() == col.null_count():
        return numbers
    flags = col.str.to_lowercase().replace_strict({"true": True, "false": False}, default=None, return_dtype=pl.Boolean)
    return flags if flags.null_count() == col.null_count() else col


def normalise(df: pl.DataFrame, source: str) -> pl.DataFrame:
    """Rename to canonical columns, convert to SI units, add row_index and the integer codes of the names
    (`_ac` aircraft, `_cs` callsign: they sort like icao24 / callsign). Raises IngestError on wrong units."""
    schema = detect_schema(df.columns, source)
    # timestamps are parsed and checked eagerly; the other columns are one select, which polars runs in parallel
    exprs = [pl.int_range(pl.len(), dtype=pl.Int64).alias("row_index")]
    typed = [_text_as_typed(df[col]) for canon, col in schema.columns.items()
             if canon not in ("ts", "icao24", "callsign") and col in df.columns and df[col].dtype in (pl.String, pl.Null)]
    if typed:  # a CSV's; Parquet columns come typed
        df = df.with_columns(typed)
    # the costly conversions (the names' tidying and codes, the timestamps: ~60 % of this step) at once
    names = {canon: col for canon, col in schema.columns.items() if canon in ("icao24", "callsign") and col in df.columns}
    *tidied, ts = together(
        *(partial(_tidy_names, df[col].cast(pl.String), lower=canon == "icao24") for canon, col in names.items()),
        partial(_timestamps, df[schema.columns["ts"]], source),
    )
    tidied = dict(zip(names, tidied))
    # which float columns hold NaN: one scan each, in one select (a scan instead of a copy where there is none)
    floats = [c for c in schema.columns.values() if c in df.columns and df[c].dtype.is_float()]
    has_nan = df.select(pl.col(floats).is_nan().any()).row(0, named=True) if floats else {}
    for canon, col in schema.columns.items():
        if col not in df.columns:
            dtype = {"callsign": pl.String, "onground": pl.Boolean}.get(canon, pl.Float64)
            exprs.append(pl.lit(None, dtype=dtype).alias(canon))
            if canon == "callsign":
                exprs.append(pl.lit(None, dtype=pl.UInt32).alias("_cs"))
            continue
        e = pl.col(col)
        if canon == "ts":
            e = pl.lit(ts)
        elif canon in ("icao24", "callsign"):
            tidy, codes = tidied[canon]
            e = pl.lit(tidy)
            exprs.append(pl.lit(codes).alias("_ac" if canon == "icao24" else "_cs"))
        elif canon == "onground":
            if df[col].dtype == pl.String:  # polars cannot cast text to booleans: a traceback
                raise IngestError(f"{source}: column '{col}' is text, expected true/false")
            e = e.cast(pl.Boolean, strict=False)
        elif canon == "pos_time":  # epoch seconds as they come, else timestamps: both to epoch µs, only ever compared
            # for equality (a repeated position), so not rounded (polars' round: 1 ms on the bundled file): two position
            # times less than 0.5 µs apart are two positions
            e = e * 1e6 if df[col].dtype == pl.Float64 else pl.lit(_timestamps(df[col], source).dt.epoch("us").cast(pl.Float64))
        else:
            if not df[col].dtype.is_numeric():
                raise IngestError(f"{source}: column '{col}' is {df[col].dtype}, expected numbers")
            e = e.cast(pl.Float64)
            if has_nan.get(col):
                e = e.fill_nan(None)
            e = e * schema.scale[canon] if schema.scale.get(canon, 1.0) != 1.0 else e
        exprs.append(e.alias(canon))
    frame = df.select(exprs)
    check_units(frame, schema, source)
    return frame


def check_units(df: pl.DataFrame, schema: Schema, source: str) -> None:
    """Catch the common unit mix-ups (feet in a metres column and vice versa) from airborne medians.

    Percentiles of an evenly spaced sample of ≤ 50,000 rows: they move by metres, the thresholds are kilometres apart."""
    # gather_every as an expression: ~3x cheaper than the frame's
    air = df.select(pl.col("alt_m", "groundspeed_mps").gather_every(max(1, df.height // UNIT_SAMPLE_ROWS))).filter(pl.col("alt_m") > 0)
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
    # Metres read as feet put a cruise at 35,000 ft near 11,000 "ft" and FL450 at 13,700; feet data flying at a
    # median ground speed above 290 kt (150 m/s) has its 95th percentile above 14,000 ft unless it was cut to
    # low levels only (250 kt IAS below FL100).
    if schema is TRAFFIC and p95_alt is not None and p95_alt < 14_000 * M_PER_FT and (gs.median() or 0) > 150:
        raise IngestError(
            f"{source}: 'altitude' stays below 14,000 while flying at airliner speed: it looks like metres or "
            "flight levels, but the traffic schema reads it as feet"
        )


# --------------------------------------------------------------------------------------------- cleaning


def _split_flights(raw: pl.DataFrame, row: np.ndarray, new: np.ndarray, callsign_row: np.ndarray) -> pl.DataFrame:
    """One row per flight of the kept rows `row` (contiguous runs, starting where `new`), in row order: flight_id =
    callsign_icao24_YYYYMMDDTHHMM from its first point (its callsign: that of callsign_row, -1: none, the icao24
    then), icao24, callsign (its last point's: a flight's rows all carry it but those before its aircraft's first
    callsign, null if none), flight_rank = rank of the name, points. Names are built once per flight."""
    first = np.flatnonzero(new)
    end = run_ends(first, len(row))
    firsts = pl.DataFrame(
        {"callsign": _callsigns(raw, callsign_row[first]), "icao24": raw["icao24"].gather(row[first]), "ts": raw["ts"].gather(row[first])}
    )
    flights = firsts.select(
        flight_id=pl.concat_str(pl.col("callsign").fill_null(pl.col("icao24")), "icao24", pl.col("ts").dt.strftime("%Y%m%dT%H%M"), separator="_"),
        icao24="icao24",
        callsign=_callsigns(raw, callsign_row[end - 1]),
        points=pl.Series(end - first),
    )
    # the rank of the name orders the flights by (flight_id, ts) comparing integers instead of strings
    return flights.with_columns(flight_rank=pl.col("flight_id").rank("dense"))


def _callsigns(raw: pl.DataFrame, rows: np.ndarray) -> pl.Series:
    """The callsigns of the raw rows `rows`, null where the row is -1 (an aircraft before its first callsign)."""
    names = raw["callsign"].gather(np.maximum(rows, 0))
    return names.set(pl.Series(rows < 0), None) if (rows < 0).any() else names


def _runs(values: np.ndarray, first: np.ndarray, length: np.ndarray) -> np.ndarray:
    """values[first:first + length] of each run, one after the other (slices copied: one Python step per flight, no
    index array per row)."""
    return np.concatenate([values[f : f + n] for f, n in zip(first.tolist(), length.tolist())]) if len(first) else values[:0]


def _rule_rows(raw: pl.DataFrame, cfg: IngestConfig, reason: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The row rules (models/aviation/kernels.py) on the normalised rows: writes each rejected row's code into
    reason[row]; returns (the rows kept, in (aircraft, ts, row) order; whether each starts a flight; the row whose
    callsign it takes, -1: none). The kernels' inputs live only here: freed before the tracks are gathered."""
    # numbers in one select (polars runs it in parallel), nulls made values no rule reads (a missing row's, a position
    # time where has_pos is false) or that mean what the rules say (a null ground speed is 0, a null callsign -1); flags
    # from their true positions (polars turns a Boolean column into numpy bit by bit, ~4x slower)
    c = {
        col.name: col.to_numpy()
        for col in raw.select(
            ac=pl.col("_ac").fill_null(0),
            ts=pl.col("ts").dt.epoch("us").fill_null(0),
            lat=pl.col("lat").fill_null(np.nan), lon=pl.col("lon").fill_null(np.nan), alt_m=pl.col("alt_m").fill_null(np.nan),
            groundspeed_mps=pl.col("groundspeed_mps").fill_null(0.0),
            pos=pl.col("pos_time").fill_null(0.0),
            cs=pl.col("_cs").cast(pl.Int64).fill_null(-1),
        ).iter_columns()
    }

    def flag(where: pl.Expr, value: bool) -> np.ndarray:
        out = np.full(raw.height, not value)
        out[raw.select(pl.arg_where(where)).to_series().to_numpy()] = value
        return out

    missing = flag(pl.any_horizontal(pl.col("ts", "_ac", "lat", "lon", "alt_m").is_null()), True)
    onground = flag(pl.col("onground").fill_null(False), True)
    has_pos = flag(pl.col("pos_time").is_null(), False)
    # read-only whether polars lent a column's memory (one chunk) or copied it (several: a Parquet file of many row
    # groups, a CSV read in parallel): numba compiles a kernel once per argument type, read-only or not included
    for a in (*c.values(), missing, onground, has_pos):
        a.setflags(write=False)
    # the first rules look at each row alone, so they run before the sort, which then orders only the rows left
    order = kernels.aircraft_time_order(c["ac"], c["ts"], missing, *TS_RANGE_US, reason)

    new, callsign_row = np.empty(len(order), dtype=bool), np.empty(len(order), dtype=np.int64)

    def rules(lo: int, hi: int) -> int:
        """The rules on order[lo:hi]: the rows kept, their flight starts and callsign rows written from lo on; how many."""
        kept = kernels.point_rules(
            order[lo:hi], c["ac"], c["ts"], c["lat"], c["lon"], c["alt_m"], onground, c["groundspeed_mps"], c["pos"], has_pos,
            cfg.min_alt_m, cfg.max_alt_m, cfg.max_speed_mps, reason,
        )
        row = kernels.speed_spikes(kept, c["ac"], c["ts"], c["lat"], c["lon"], c["alt_m"], cfg.max_speed_mps, cfg.max_climb_mps, EARTH_RADIUS_M, reason)
        kernels.flight_starts(row, c["ac"], c["ts"], c["cs"], cfg.gap_split_s, new[lo : lo + row.size], callsign_row[lo : lo + row.size])
        return row.size

    # every rule looks at one aircraft's rows only: the two halves of the rows, cut between two aircraft, at once
    # (the kernels release the GIL); the second half's results then move up behind the first's, in place
    mid = len(order) // 2
    if mid:
        mid = bisect_right(range(len(order)), c["ac"][order[mid - 1]], lo=mid, key=lambda k: c["ac"][order[k]])
    n1, n2 = together(partial(rules, 0, mid), partial(rules, mid, len(order)))
    for a in (order, new, callsign_row):
        a[n1 : n1 + n2] = a[mid : mid + n2]
    return order[: n1 + n2], new[: n1 + n2], callsign_row[: n1 + n2]


def clean(raw: pl.DataFrame, source: str, cfg: IngestConfig = IngestConfig()) -> tuple[pl.DataFrame, pl.DataFrame, dict[str, int]]:
    """Normalised rows (`normalise`'s output: row_index is the row's position) -> (cleaned points with
    flight_id, rejects with reason, rows rejected per reason). Every row ends in one.

    Rules, each rejected row getting the first reason that hits it: a missing time, aircraft or position; a time
    outside 1970-2100 (out of range); then, on the rows sorted by (aircraft, ts, row), a duplicate, a point on the
    ground or out of range; of the rows left, a repeated (stale) position; of those, a speed or climb spike
    (`_rule_rows`); last, a flight (split at a long gap or a callsign change) of fewer than min_points rows. Each
    rejected row's reason goes into one array; the tracks and the rejects are then gathered from the raw rows once
    each, in their final order."""
    reason = np.zeros(raw.height, dtype=np.uint8)  # per raw row: 0 kept, else its code (kernels.REASONS)
    row, new, callsign_row = _rule_rows(raw, cfg, reason)
    flights = _split_flights(raw, row, new, callsign_row)
    # rows are in (aircraft, ts) order and a flight_id names one aircraft, so the flights (contiguous runs of
    # rows) put in the order of their names, stably, give (flight_id, ts) order: one gather of whole runs
    # instead of sorting the rows, which also leaves out the runs too short to keep
    points = flights["points"].to_numpy()
    first = np.cumsum(points) - points
    short = points < cfg.min_points
    reason[_runs(row, first[short], points[short])] = kernels.SHORT_SEGMENT
    order = np.flatnonzero(~short)
    order = order[np.argsort(flights["flight_rank"].to_numpy()[order], kind="stable")]
    columns = ("ts", "lat", "lon", "alt_m", "groundspeed_mps", "track_deg", "vertical_rate_mps")
    tracks = raw.select(columns)[_runs(row, first[order], points[order])]
    # the names are the flight's on every row (gathered from the flights, not from the raw rows), but for the rows
    # before the aircraft's first callsign (a prefix of its first flight), which keep their icao24 as callsign, as does
    # a flight without one: downstream keys are never null
    names = flights.select("flight_id", "icao24", "callsign")[np.repeat(order, points[order])]
    callsign, at = names["callsign"], np.cumsum(points[order]) - points[order]
    late = np.flatnonzero(callsign_row[first[order]] < 0)  # the flights whose first row has no callsign yet
    if len(late):
        unnamed = np.concatenate(
            [at[j] + np.flatnonzero(callsign_row[first[f] : first[f] + points[f]] < 0) for j, f in zip(late, order[late])]
        )
        callsign = callsign.scatter(unnamed, names["icao24"].gather(unnamed))
    # flight_id flagged sorted: checks downstream are free
    tracks = tracks.with_columns(names["flight_id"].set_sorted(), names["icao24"], callsign).select(
        "flight_id", "ts", "icao24", "callsign", "lat", "lon", "alt_m", "groundspeed_mps", "track_deg", "vertical_rate_mps"
    )
    # rejects in row order: the positions of the nonzero reasons are already sorted (found in a boolean mask: numpy's
    # nonzero of the uint8 codes themselves: 0.8 against 0.2 ms on the bundled file)
    out = np.flatnonzero(reason != 0)
    code = reason[out] - 1
    rejects = pl.concat(
        [
            pl.DataFrame({"row_index": out, "reason": pl.Series(kernels.REASONS).gather(code)}),
            raw.select("icao24", "callsign", "ts", "lat", "lon", "alt_m")[out],
        ],
        how="horizontal",
    ).with_columns(source=pl.lit(source))
    # counted from the codes: grouping the rejects' reason strings cost ~1.5 ms on the bundled file
    rejected = {kernels.REASONS[c]: int(n) for c, n in enumerate(np.bincount(code, minlength=len(kernels.REASONS))) if n}
    return tracks, rejects, rejected


def summarise(source: str, n_read: int, kept: int, rejected: dict[str, int]) -> pl.DataFrame:
    """Row accounting: read = kept + sum(rejected per reason), the reasons in alphabetical order."""
    reasons = sorted(rejected)
    return pl.DataFrame(
        {
            "source": [source] * (2 + len(reasons)),
            "outcome": ["read", "kept"] + ["rejected"] * len(reasons),
            "reason": ["", "", *reasons],
            "rows": [n_read, kept, *(rejected[r] for r in reasons)],
        },
        schema={"source": pl.String, "outcome": pl.String, "reason": pl.String, "rows": pl.Int64},
    )


def ingest(path: str | Path, cfg: IngestConfig = IngestConfig()) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """Read one file -> (cleaned tracks, rejects, summary). Raises IngestError on unusable input."""
    source = Path(path).name
    raw = normalise(read_source(path), source)
    tracks, rejects, rejected = clean(raw, source, cfg)
    summary = summarise(source, raw.height, tracks.height, rejected)
    assert tracks.height + rejects.height == raw.height, "row accounting broken"
    return tracks, rejects, summary
