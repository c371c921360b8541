"""Flight ingest: a state-vector file -> flight_tracks, flights, ingest_rejects, ingest_summary."""

from pathlib import Path

import dagster as dg
from pydantic import Field

from models.aviation.airports import flights_table
from models.aviation.ingest import IngestConfig, IngestError, ingest

REPO = Path(__file__).resolve().parents[2]
DEFAULT_TRACKS = REPO / "data" / "opensky" / "kaliningrad_2022-02-22_2022-03-05.parquet"
_D = IngestConfig()


class FlightIngestConfig(dg.Config):
    source_path: str = Field(
        default=str(DEFAULT_TRACKS),
        description="OpenSky state vectors or a traffic-style table (.parquet, .csv, .json[.gz]); "
        "default: the bundled Kaliningrad flights",
    )
    gap_split_s: float = Field(default=_D.gap_split_s, description="a silence longer than this starts a new flight [s]")
    min_points: int = Field(default=_D.min_points, description="received positions a flight needs to be kept")
    max_alt_m: float = Field(default=_D.max_alt_m, description="altitudes above this are rejected as out_of_range [m]")
    max_speed_mps: float = Field(default=_D.max_speed_mps, description="implied speed that flags a position spike [m/s]")


@dg.multi_asset(
    group_name="aviation",
    outs={
        "flight_tracks": dg.AssetOut(description="Cleaned state vectors split into flights."),
        "flights": dg.AssetOut(description="One row per flight with inferred origin and destination."),
        "ingest_rejects": dg.AssetOut(description="Quarantine: every rejected input row with its reason."),
        "ingest_summary": dg.AssetOut(description="Row accounting: read = kept + rejected per reason."),
    },
)
def flight_ingest(context: dg.AssetExecutionContext, config: FlightIngestConfig):
    cfg = IngestConfig(
        gap_split_s=config.gap_split_s,
        min_points=config.min_points,
        max_alt_m=config.max_alt_m,
        max_speed_mps=config.max_speed_mps,
    )
    tracks, rejects, summary = ingest(config.source_path, cfg)
    flights = flights_table(tracks)
    counts = {f"{r['outcome']} {r['reason']}".strip(): r["rows"] for r in summary.iter_rows(named=True)}
    if flights.height == 0:  # empty tables would replace the warehouse's and every check downstream would fail
        raise IngestError(f"{config.source_path}: no flight kept of {counts['read']:,} rows ("
                          + ", ".join(f"{k.removeprefix('rejected ')}={v:,}" for k, v in counts.items() if k.startswith("rejected"))
                          + "); check the thresholds (gap_split_s, min_points, max_alt_m, max_speed_mps)")
    context.log.info(f"ingested {config.source_path}: " + ", ".join(f"{k}={v:,}" for k, v in counts.items()))
    routes = dict(flights["route"].value_counts().rows())
    context.log.info(f"{flights.height} flights on routes {routes}")
    return (
        dg.Output(tracks, metadata={"source": config.source_path, "flights": flights.height}),
        dg.Output(flights, metadata={"routes": dg.MetadataValue.json(routes)}),
        dg.Output(rejects, metadata={"by_reason": dg.MetadataValue.json(counts)}),
        dg.Output(summary, metadata={"read": counts["read"], "kept": counts["kept"]}),
    )
