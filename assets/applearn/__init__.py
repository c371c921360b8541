"""AppLearn inverse RL assets (chapter 6, issue 3; Dagster group `trajectory`): exposes ASSETS, CHECKS and JOBS."""

import dagster as dg

from assets.applearn import checks, models

ASSETS = dg.load_assets_from_modules([models])
CHECKS = checks.CHECKS
JOBS: list = []
