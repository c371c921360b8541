"""Trajectory-imitation assets (issue 3): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

import dagster as dg

from assets.jobs import group_job
from assets.trajectory import checks, evaluation, models, report

ASSETS = dg.load_assets_from_modules([models, evaluation, report])
CHECKS = checks.CHECKS
JOBS = [group_job("trajectory_imitation", "trajectory", "Train multi-modal GAIL (MMIL/SMIL), BC, AppLearn and the SVM baseline; evaluate with baselines on held-out flights; report.")]
