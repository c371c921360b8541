"""The one Dagster code location: `dagster dev` / `dagster asset materialize -m pipelines.definitions`."""

import dagster as dg

from assets.aviation import checks, ingest, modes, tracks, weather
from warehouse.io_manager import ParquetIOManager

aviation_assets = dg.load_assets_from_modules([ingest, weather, tracks, modes])

aviation_data_job = dg.define_asset_job(
    "aviation_data",
    selection=dg.AssetSelection.groups("aviation"),
    description="Ingest flights and weather, resample to constant steps, segment phases, cluster modes, split.",
)

defs = dg.Definitions(
    assets=aviation_assets,
    asset_checks=checks.CHECKS,
    jobs=[aviation_data_job],
    resources={"io_manager": ParquetIOManager()},
    # one process: on 2 cores, a process per step spends more time importing than computing
    executor=dg.in_process_executor,
)
