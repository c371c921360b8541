"""Demand and airspace: a day of flights (bundled Swiss ADS-B day or a user SO6 file) cut into sector entries."""

from pathlib import Path

import dagster as dg
from pydantic import Field

from models.dcb.airspace import GridSectorisation
from models.dcb.experiment import airspace_tables, load_demand, sectorisation

REPO = Path(__file__).resolve().parents[2]
DEFAULT_DEMAND = REPO / "data" / "traffic_samples" / "switzerland_2018-08-01.parquet"


class AirspaceConfig(dg.Config):
    source_path: str = Field(default=str(DEFAULT_DEMAND), description="ADS-B / traffic-style table (.parquet, .csv, .json[.gz]; "
                             "read by the foundation ingest) or a EUROCONTROL SO6 file (.so6); default: the bundled Swiss day")
    min_points: int = Field(default=6, description="ADS-B: received positions a flight needs (6 = 1 min at 10 s)")
    so6_step_s: float = Field(default=30.0, description="SO6: segments are densified to a point every this many seconds [s]")
    sector_geojson: str | None = Field(default=None, description="GeoJSON FeatureCollection of sector polygons with properties "
                                       "name, fl_lower, fl_upper (and optional capacity_per_h); None: the grid below")
    cell_lat_deg: float = Field(default=GridSectorisation.cell_lat_deg, description="grid: cell height [deg latitude]")
    cell_lon_deg: float = Field(default=GridSectorisation.cell_lon_deg, description="grid: cell width [deg longitude]")
    fl_edges: list[float] = Field(default=list(GridSectorisation.fl_edges), description="grid: flight-level band edges (FL)")
    box: list[float] | None = Field(default=None, description="grid: [lat_min, lat_max, lon_min, lon_max] [deg]; None: the Swiss box")


@dg.multi_asset(
    group_name="dcb",
    outs={
        "dcb_sectors": dg.AssetOut(description="Sectors with their base hourly capacity."),
        "dcb_flights": dg.AssetOut(description="Flights of the day with aircraft class and delay cost."),
        "dcb_sector_entries": dg.AssetOut(description="Sector entry/exit events of every flight."),
        "dcb_demand_rejects": dg.AssetOut(description="Quarantine of unusable input rows / SO6 lines."),
        "dcb_demand_summary": dg.AssetOut(description="Row accounting of the demand input."),
    },
)
def dcb_airspace(context: dg.AssetExecutionContext, config: AirspaceConfig):
    points, flights, rejects, summary = load_demand(config.source_path, config.min_points, config.so6_step_s)
    sectoriser = sectorisation(config.sector_geojson, config.cell_lat_deg, config.cell_lon_deg, config.fl_edges, config.box)
    sectors, flights, entries = airspace_tables(points, flights, sectoriser)
    counts = {f"{o} {r}".strip(): n for _, o, r, n in summary.iter_rows()}
    context.log.info(f"{config.source_path}: {counts}; {flights.height} flights, {entries.height} entries into {sectors.height} sectors")
    return (
        dg.Output(sectors, metadata={"sectors": sectors.height, "sector_file": config.sector_geojson or "grid"}),
        dg.Output(flights, metadata={"flights": flights.height, "in_airspace": int((flights["n_entries"] > 0).sum())}),
        dg.Output(entries, metadata={"entries": entries.height}),
        dg.Output(rejects, metadata={"by_reason": dg.MetadataValue.json(counts)}),
        dg.Output(summary, metadata={"read": counts["read"], "kept": counts["kept"]}),
    )
