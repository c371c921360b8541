"""Scenario generation: unsignalized networks + route agents (urban_routes), seeded demand copies (urban_scenarios)."""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.profiles import default_profile
from models.urban.experiments import networks, routes_table, scenarios, scenarios_table
from warehouse.storage import home


class RoutesConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo: Sc1 + the bundled real network; paper: also Sc2 and Sc4")
    user_network: str | None = Field(
        default=None,
        description="optional extra network 'user': any OpenStreetMap extract (.osm/.osm.gz, through netconvert) or SUMO .net.xml[.gz]",
    )
    seed: int = Field(default=0, description="seed of the route sample where a network has more routes than route agents")


@dg.asset(group_name="urban", description="Unsignalized SUMO networks (netgenerate / netconvert) and their routes, one row per route agent route.")
def urban_routes(context: dg.AssetExecutionContext, config: RoutesConfig) -> dg.Output:
    t = time.perf_counter()
    df = routes_table(networks(config.profile, config.user_network), home() / "sumo" / "networks", config.seed)
    summary = df.group_by("network", maintain_order=True).agg(pl.col("n_junctions").first(), routes=pl.len())
    context.log.info(f"networks built in {time.perf_counter() - t:.1f} s: {summary.rows()}")
    return dg.Output(df, metadata={"networks": dg.MetadataValue.json(summary.to_dicts())})


class ScenariosConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo: Sc1 and real CR trained, MR/LR and 3x copies evaluated; paper: Tables 4.2-4.9")
    artificial_cars_only: bool = Field(default=False, description="passenger cars only on Sc1/Sc2/Sc4 and their copies (as Table 4.2's "
                                       "one route agent per route suggests the thesis had); default: the 75/15/10 mix everywhere")


@dg.asset(group_name="urban", description="Seeded scenario copies (train / eval / reuse): SUMO route and vehicle-type files, 75/15/10 vehicle mix.")
def urban_scenarios(context: dg.AssetExecutionContext, config: ScenariosConfig, urban_routes: pl.DataFrame) -> dg.Output:
    specs = scenarios(config.profile, user_network="user" in set(urban_routes["network"]), artificial_cars_only=config.artificial_cars_only)
    df = scenarios_table(specs, urban_routes, home() / "sumo" / "scenarios")
    counts = df.group_by("scenario", "role", maintain_order=True).agg(copies=pl.len(), vehicles=pl.col("n_vehicles").sum())
    context.log.info(f"{df.height} scenario copies written: {counts.rows()}")
    return dg.Output(df, metadata={"copies": dg.MetadataValue.json(counts.to_dicts())})
