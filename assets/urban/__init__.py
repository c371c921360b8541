"""Urban traffic assets (issue 4): SUMO scenarios, route-agent DDQN training, evaluation against IDM/Krauss."""

import dagster as dg

from assets.urban import checks, evaluation, scenarios, training

ASSETS = dg.load_assets_from_modules([scenarios, training, evaluation])
CHECKS = checks.CHECKS
JOBS = [
    dg.define_asset_job(
        "urban",
        selection=dg.AssetSelection.groups("urban"),
        description="Generate unsignalized SUMO scenarios, train col-MARL / i-MARL route agents, evaluate against IDM and Krauss.",
    )
]
