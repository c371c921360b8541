"""Urban traffic assets (issue 4): SUMO scenarios, route-agent DDQN training, evaluation against IDM/Krauss."""

import dagster as dg

from assets.jobs import group_job
from assets.urban import checks, evaluation, scenarios, training

ASSETS = dg.load_assets_from_modules([scenarios, training, evaluation])
CHECKS = checks.CHECKS
JOBS = [group_job("urban", "urban", "Generate unsignalized SUMO scenarios, train col-MARL / i-MARL route agents, evaluate against IDM and Krauss.")]
