"""Tables of the flight-data pipeline (issue 2): ingest, weather, 20 s tracks, phases, modes, splits."""

import pyarrow as pa

from warehouse.table import TS, Table, col

_FLIGHT_ID = col("flight_id", pa.string(), "", "callsign_icao24_YYYYMMDDTHHMM of the first point (UTC)")
_PHASE = col("phase", pa.string(), "", "flight phase: climb, cruise or descent")

TABLES: list[Table] = [
    Table(
        "flight_tracks",
        "Cleaned state vectors: one row per received position, on-ground/duplicate/impossible points removed, "
        "split into flights on time gaps.",
        (
            _FLIGHT_ID,
            col("ts", TS, "UTC", "time the position was received"),
            col("icao24", pa.string(), "", "ICAO 24-bit transponder address, lower-case hex"),
            col("callsign", pa.string(), "", "callsign, stripped"),
            col("lat", pa.float64(), "deg", "WGS84 latitude"),
            col("lon", pa.float64(), "deg", "WGS84 longitude"),
            col("alt_m", pa.float64(), "m", "barometric altitude"),
            col("groundspeed_mps", pa.float64(), "m/s", "ground speed", nullable=True),
            col("track_deg", pa.float64(), "deg", "true track over ground, 0 = north, clockwise", nullable=True),
            col("vertical_rate_mps", pa.float64(), "m/s", "vertical rate, positive up", nullable=True),
        ),
    ),
    Table(
        "flights",
        "One row per flight found by the ingest, with inferred origin and destination airports.",
        (
            _FLIGHT_ID,
            col("callsign", pa.string(), "", "callsign"),
            col("icao24", pa.string(), "", "ICAO 24-bit transponder address"),
            col("origin", pa.string(), "", "ICAO code of the inferred origin airport"),
            col("destination", pa.string(), "", "ICAO code of the inferred destination airport"),
            col("route", pa.string(), "", "origin-destination, e.g. UUEE-UMKK"),
            col("origin_distance_nm", pa.float64(), "NM", "distance from the first point to the origin airport"),
            col(
                "destination_distance_nm",
                pa.float64(),
                "NM",
                "distance from the last point to the destination airport (coverage often ends before landing)",
            ),
            col("first_ts", TS, "UTC", "first cleaned point"),
            col("last_ts", TS, "UTC", "last cleaned point"),
            col("n_points", pa.int64(), "", "cleaned points"),
        ),
    ),
    Table(
        "ingest_rejects",
        "Quarantine: every input row the ingest did not keep, with the reason. kept + rejected = read.",
        (
            col("source", pa.string(), "", "input file"),
            col("row_index", pa.int64(), "", "0-based row number in the input file"),
            col(
                "reason",
                pa.string(),
                "",
                "missing_value, duplicate_row, repeated_position, on_ground, out_of_range (a position, altitude or ground "
                "speed beyond the physical limits, or a time outside 1970–2100), speed_spike or short_segment",
            ),
            col("icao24", pa.string(), "", "as read", nullable=True),
            col("callsign", pa.string(), "", "as read", nullable=True),
            col("ts", TS, "UTC", "as read", nullable=True),
            col("lat", pa.float64(), "deg", "as read", nullable=True),
            col("lon", pa.float64(), "deg", "as read", nullable=True),
            col("alt_m", pa.float64(), "m", "as read, converted to metres", nullable=True),
        ),
    ),
    Table(
        "ingest_summary",
        "Row accounting per ingest: rows read, kept, and rejected per reason (outcome = read, kept or rejected).",
        (
            col("source", pa.string(), "", "input file"),
            col("outcome", pa.string(), "", "read, kept or rejected"),
            col("reason", pa.string(), "", "reject reason; empty for read and kept"),
            col("rows", pa.int64(), "", "row count"),
        ),
    ),
    Table(
        "weather",
        "Tidy weather grid read from ERA5 NetCDF or GFS GRIB2: one row per time, pressure level and grid node.",
        (
            col("time", TS, "UTC", "valid time of the field, as in the source file (alignment to the flights happens in tracks_20s)"),
            col("level_hpa", pa.float64(), "hPa", "isobaric level"),
            col("lat", pa.float64(), "deg", "grid latitude"),
            col("lon", pa.float64(), "deg", "grid longitude, -180..180"),
            col("temperature_k", pa.float64(), "K", "air temperature"),
            col("wind_u_mps", pa.float64(), "m/s", "eastward wind"),
            col("wind_v_mps", pa.float64(), "m/s", "northward wind"),
        ),
    ),
    Table(
        "tracks_20s",
        "Constant-step tracks (default 20 s; constant speed between received positions), "
        "with weather at each 4D point and the flight phase.",
        (
            _FLIGHT_ID,
            col("ts", TS, "UTC", "time of the point, a multiple of the step"),
            col("lat", pa.float64(), "deg", "latitude"),
            col("lon", pa.float64(), "deg", "longitude"),
            col("alt_m", pa.float64(), "m", "barometric altitude"),
            col("groundspeed_mps", pa.float64(), "m/s", "ground speed"),
            col("track_deg", pa.float64(), "deg", "true track, 0..360"),
            col("vertical_rate_mps", pa.float64(), "m/s", "vertical rate, positive up"),
            col("temperature_k", pa.float64(), "K", "air temperature at the point's ISA pressure level"),
            col("wind_u_mps", pa.float64(), "m/s", "eastward wind at the point"),
            col("wind_v_mps", pa.float64(), "m/s", "northward wind at the point"),
            _PHASE,
        ),
    ),
    Table(
        "flight_phases",
        "One row per flight and phase, in the order climb, cruise, descent (a phase can be absent).",
        (
            _FLIGHT_ID,
            _PHASE,
            col("start_ts", TS, "UTC", "first point of the phase"),
            col("end_ts", TS, "UTC", "last point of the phase"),
            col("n_points", pa.int64(), "", "points of the phase in tracks_20s"),
        ),
    ),
    Table(
        "trajectory_modes",
        "Route modality of each flight, per phase and for the whole trajectory (phase = all): "
        "DTW/sqrt(d*L) distances, Ward linkage, cluster count by silhouette, clustered per route.",
        (
            _FLIGHT_ID,
            col("route", pa.string(), "", "origin-destination the clustering ran within"),
            col("phase", pa.string(), "", "all, climb, cruise or descent"),
            col("mode", pa.int64(), "", "cluster id, 0-based, numbered by size (0 = largest)"),
            col("n_modes", pa.int64(), "", "clusters chosen by silhouette for this route and phase"),
            col("silhouette", pa.float64(), "", "silhouette score of the chosen clustering", nullable=True),
        ),
    ),
    Table(
        "flight_splits",
        "Seeded train/test split by flight, stratified by route and whole-trajectory mode.",
        (
            _FLIGHT_ID,
            col("route", pa.string(), "", "origin-destination"),
            col("split", pa.string(), "", "train or test"),
            col("seed", pa.int64(), "", "seed of the split"),
        ),
    ),
]
