"""The one Dagster code location: `dagster dev` / `dagster asset materialize -m pipelines.definitions`.

Each system's assets package (`assets/<system>/__init__.py`) exposes ASSETS, CHECKS and JOBS.
"""

import dagster as dg

from assets import applearn, aviation, dcb, trajectory, urban
from warehouse.io_manager import ParquetIOManager

SYSTEMS = (aviation, trajectory, applearn, urban, dcb)

defs = dg.Definitions(
    assets=[a for s in SYSTEMS for a in s.ASSETS],
    asset_checks=[c for s in SYSTEMS for c in s.CHECKS],
    jobs=[j for s in SYSTEMS for j in s.JOBS],
    resources={"io_manager": ParquetIOManager()},
    # one process: on 2 cores, a process per step spends more time importing than computing
    executor=dg.in_process_executor,
)
