"""One job per asset group, so `dagster job execute -j <name>` runs a whole system."""

import dagster as dg


def group_job(name: str, group: str, description: str):
    return dg.define_asset_job(name, selection=dg.AssetSelection.groups(group), description=description)
