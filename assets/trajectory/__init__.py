"""Trajectory-imitation assets (issue 3): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

import dagster as dg

from assets.trajectory import checks, evaluation, models, report

ASSETS = dg.load_assets_from_modules([models, evaluation, report])
CHECKS = checks.CHECKS
JOBS = [
    dg.define_asset_job(
        "trajectory_imitation",
        selection=dg.AssetSelection.groups("trajectory"),
        description="Train multi-modal GAIL (MMIL/SMIL), BC, AppLearn and the SVM baseline; evaluate with baselines on held-out flights; report.",
    )
]
