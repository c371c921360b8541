"""Every warehouse table's schema, declared once.

The IO manager enforces these on write, the DuckDB layer exposes one view per table, and the README's
data dictionary is generated from the same declarations (`python -m warehouse schema --markdown`).
Units live in the column name where they could be ambiguous (alt_m, speed_mps) and in `unit` always.
"""

from dataclasses import dataclass

import pyarrow as pa

TS = pa.timestamp("us", tz="UTC")


@dataclass(frozen=True)
class Column:
    name: str
    type: pa.DataType
    unit: str
    description: str
    nullable: bool = False


@dataclass(frozen=True)
class Table:
    name: str
    description: str
    columns: tuple[Column, ...]

    @property
    def schema(self) -> pa.Schema:
        return pa.schema(
            [pa.field(c.name, c.type, nullable=c.nullable) for c in self.columns],
            metadata={"table": self.name, "description": self.description},
        )


def _c(name, type_, unit, description, nullable=False) -> Column:
    return Column(name, type_, unit, description, nullable)


_FLIGHT_ID = _c("flight_id", pa.string(), "", "callsign_icao24_YYYYMMDDTHHMM of the first point (UTC)")
_PHASE = _c("phase", pa.string(), "", "flight phase: climb, cruise or descent")

TABLES: dict[str, Table] = {
    t.name: t
    for t in [
        Table(
            "flight_tracks",
            "Cleaned state vectors: one row per received position, on-ground/duplicate/impossible points removed, "
            "split into flights on time gaps.",
            (
                _FLIGHT_ID,
                _c("ts", TS, "UTC", "time the position was received"),
                _c("icao24", pa.string(), "", "ICAO 24-bit transponder address, lower-case hex"),
                _c("callsign", pa.string(), "", "callsign, stripped"),
                _c("lat", pa.float64(), "deg", "WGS84 latitude"),
                _c("lon", pa.float64(), "deg", "WGS84 longitude"),
                _c("alt_m", pa.float64(), "m", "barometric altitude"),
                _c("groundspeed_mps", pa.float64(), "m/s", "ground speed", nullable=True),
                _c("track_deg", pa.float64(), "deg", "true track over ground, 0 = north, clockwise", nullable=True),
                _c("vertical_rate_mps", pa.float64(), "m/s", "vertical rate, positive up", nullable=True),
            ),
        ),
        Table(
            "flights",
            "One row per flight found by the ingest, with inferred origin and destination airports.",
            (
                _FLIGHT_ID,
                _c("callsign", pa.string(), "", "callsign"),
                _c("icao24", pa.string(), "", "ICAO 24-bit transponder address"),
                _c("origin", pa.string(), "", "ICAO code of the inferred origin airport"),
                _c("destination", pa.string(), "", "ICAO code of the inferred destination airport"),
                _c("route", pa.string(), "", "origin-destination, e.g. UUEE-UMKK"),
                _c("origin_distance_nm", pa.float64(), "NM", "distance from the first point to the origin airport"),
                _c(
                    "destination_distance_nm",
                    pa.float64(),
                    "NM",
                    "distance from the last point to the destination airport (coverage often ends before landing)",
                ),
                _c("first_ts", TS, "UTC", "first cleaned point"),
                _c("last_ts", TS, "UTC", "last cleaned point"),
                _c("n_points", pa.int64(), "", "cleaned points"),
            ),
        ),
        Table(
            "ingest_rejects",
            "Quarantine: every input row the ingest did not keep, with the reason. kept + rejected = read.",
            (
                _c("source", pa.string(), "", "input file"),
                _c("row_index", pa.int64(), "", "0-based row number in the input file"),
                _c(
                    "reason",
                    pa.string(),
                    "",
                    "missing_value, duplicate_row, repeated_position, on_ground, out_of_range, "
                    "speed_spike or short_segment",
                ),
                _c("icao24", pa.string(), "", "as read", nullable=True),
                _c("callsign", pa.string(), "", "as read", nullable=True),
                _c("ts", TS, "UTC", "as read", nullable=True),
                _c("lat", pa.float64(), "deg", "as read", nullable=True),
                _c("lon", pa.float64(), "deg", "as read", nullable=True),
                _c("alt_m", pa.float64(), "m", "as read, converted to metres", nullable=True),
            ),
        ),
        Table(
            "ingest_summary",
            "Row accounting per ingest: rows read, kept, and rejected per reason (outcome = read, kept or rejected).",
            (
                _c("source", pa.string(), "", "input file"),
                _c("outcome", pa.string(), "", "read, kept or rejected"),
                _c("reason", pa.string(), "", "reject reason; empty for read and kept"),
                _c("rows", pa.int64(), "", "row count"),
            ),
        ),
        Table(
            "weather",
            "Tidy weather grid read from ERA5 NetCDF or GFS GRIB2: one row per time, pressure level and grid node.",
            (
                _c("time", TS, "UTC", "valid time of the field, as in the source file (alignment to the flights happens in tracks_20s)"),
                _c("level_hpa", pa.float64(), "hPa", "isobaric level"),
                _c("lat", pa.float64(), "deg", "grid latitude"),
                _c("lon", pa.float64(), "deg", "grid longitude, -180..180"),
                _c("temperature_k", pa.float64(), "K", "air temperature"),
                _c("wind_u_mps", pa.float64(), "m/s", "eastward wind"),
                _c("wind_v_mps", pa.float64(), "m/s", "northward wind"),
            ),
        ),
        Table(
            "tracks_20s",
            "Constant-step tracks (default 20 s; constant speed between received positions), "
            "with weather at each 4D point and the flight phase.",
            (
                _FLIGHT_ID,
                _c("ts", TS, "UTC", "time of the point, a multiple of the step"),
                _c("lat", pa.float64(), "deg", "latitude"),
                _c("lon", pa.float64(), "deg", "longitude"),
                _c("alt_m", pa.float64(), "m", "barometric altitude"),
                _c("groundspeed_mps", pa.float64(), "m/s", "ground speed"),
                _c("track_deg", pa.float64(), "deg", "true track, 0..360"),
                _c("vertical_rate_mps", pa.float64(), "m/s", "vertical rate, positive up"),
                _c("temperature_k", pa.float64(), "K", "air temperature at the point's ISA pressure level"),
                _c("wind_u_mps", pa.float64(), "m/s", "eastward wind at the point"),
                _c("wind_v_mps", pa.float64(), "m/s", "northward wind at the point"),
                _PHASE,
            ),
        ),
        Table(
            "flight_phases",
            "One row per flight and phase, in the order climb, cruise, descent (a phase can be absent).",
            (
                _FLIGHT_ID,
                _PHASE,
                _c("start_ts", TS, "UTC", "first point of the phase"),
                _c("end_ts", TS, "UTC", "last point of the phase"),
                _c("n_points", pa.int64(), "", "points of the phase in tracks_20s"),
            ),
        ),
        Table(
            "trajectory_modes",
            "Route modality of each flight, per phase and for the whole trajectory (phase = all): "
            "DTW/sqrt(d*L) distances, Ward linkage, cluster count by silhouette, clustered per route.",
            (
                _FLIGHT_ID,
                _c("route", pa.string(), "", "origin-destination the clustering ran within"),
                _c("phase", pa.string(), "", "all, climb, cruise or descent"),
                _c("mode", pa.int64(), "", "cluster id, 0-based, numbered by size (0 = largest)"),
                _c("n_modes", pa.int64(), "", "clusters chosen by silhouette for this route and phase"),
                _c("silhouette", pa.float64(), "", "silhouette score of the chosen clustering", nullable=True),
            ),
        ),
        Table(
            "flight_splits",
            "Seeded train/test split by flight, stratified by route and whole-trajectory mode.",
            (
                _FLIGHT_ID,
                _c("route", pa.string(), "", "origin-destination"),
                _c("split", pa.string(), "", "train or test"),
                _c("seed", pa.int64(), "", "seed of the split"),
            ),
        ),
    ]
}


def data_dictionary_markdown() -> str:
    """The README's data dictionary: one section per table, one row per column."""
    parts = []
    for t in TABLES.values():
        parts.append(f"#### `{t.name}`\n\n{t.description}\n\n| column | type | unit | description |\n|---|---|---|---|")
        for c in t.columns:
            parts.append(f"| `{c.name}` | {c.type} | {c.unit} | {c.description} |")
        parts.append("")
    return "\n".join(parts)
