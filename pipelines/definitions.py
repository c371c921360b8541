"""The one Dagster code location: `dagster dev` / `dagster asset materialize -m pipelines.definitions`.

Each system's assets package (`assets/<system>/__init__.py`) exposes ASSETS, CHECKS and JOBS.
"""

import dagster as dg

from assets import applearn, aviation, dcb, trajectory, urban
from pipelines.progress import progress_logger
from warehouse.io_manager import ParquetIOManager

SYSTEMS = (aviation, trajectory, applearn, urban, dcb)

defs = dg.Definitions(
    assets=[a for s in SYSTEMS for a in s.ASSETS],
    asset_checks=[c for s in SYSTEMS for c in s.CHECKS],
    jobs=[j for s in SYSTEMS for j in s.JOBS],
    resources={"io_manager": ParquetIOManager()},
    # Dagster's console logger stays the default; `progress` runs only when a run's config names it
    loggers={"console": dg.colored_console_logger, "progress": progress_logger},
    # one process: on 2 cores, a process per step spends more time importing than computing
    executor=dg.in_process_executor,
)
