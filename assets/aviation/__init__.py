"""Flight-data pipeline assets (issue 2): ingest, weather, 20 s tracks, phases, modes, splits."""

import dagster as dg

from assets.jobs import group_job
from assets.aviation import checks, ingest, modes, tracks, weather

ASSETS = dg.load_assets_from_modules([ingest, weather, tracks, modes])
CHECKS = checks.CHECKS
JOBS = [group_job("aviation_data", "aviation", "Ingest flights and weather, resample to constant steps, segment phases, cluster modes, split.")]
