"""Air traffic congestion (DCB) assets (issue 5): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

import dagster as dg

from assets.jobs import group_job
from assets.dcb import airspace, cases, checks, results, training

ASSETS = dg.load_assets_from_modules([airspace, cases, training, results])
CHECKS = checks.CHECKS
JOBS = [group_job("dcb", "dcb", "Load a day of traffic and a sectorisation, find the hotspots, solve them exactly and with every learner, report.")]
