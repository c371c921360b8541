"""Trained trajectory models: every GAIL variant under MMIL and SMIL, and BC, for every seed.

tracks_20s, trajectory_modes, flights, flight_splits, weather -> trajectory_models (catalogue + model files)
"""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.profiles import check_names, default_profile, resolve
from warehouse.artifacts import artifact_path


class TrajectoryModelsConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo (minutes on 2 cores) or paper (thesis budgets)")
    seeds: list[int] | None = Field(default=None, description="training seeds [demo 0-4, paper 0-9]")
    bc_epochs: int | None = Field(default=None, description="BC epochs, also the GAILs' warm start [demo 20, paper 200]")
    gail_iterations: int | None = Field(default=None, description="adversarial iterations per phase model [demo 3, paper 300]")
    discriminators: list[str] | None = Field(default=None, description="bce_gp and/or wgan_gp [demo bce_gp, paper both]")
    algorithms: list[str] | None = Field(default=None, description="triple_gail and/or sinfo_gail [both]")
    dt_s: float = Field(default=20.0, description="time step of the tracks the models learn from [s]")
    workers: int | None = Field(default=None, description="bundles trained in parallel, one process (one core) each [None: the usable cores]")


def training_plan(config: TrajectoryModelsConfig) -> dict:
    """The profile's settings with the config's overrides; one line, before any work, for an unknown discriminator
    or algorithm, or none at all."""
    from models.trajectory.ppo import DISCRIMINATORS
    from models.trajectory.training import GAILS, PROFILE_DEFAULTS

    p = resolve(config, PROFILE_DEFAULTS)
    check_names("discriminators", p["discriminators"], DISCRIMINATORS)
    check_names("algorithms", p["algorithms"], GAILS)
    return p


@dg.asset(group_name="trajectory", description="Trained multi-modal GAIL (MMIL, SMIL) and BC models per seed; one model file each.")
def trajectory_models(context: dg.AssetExecutionContext, config: TrajectoryModelsConfig, tracks_20s: pl.DataFrame,
                      trajectory_modes: pl.DataFrame, flights: pl.DataFrame, flight_splits: pl.DataFrame, weather: pl.DataFrame):
    import torch

    from models.markdown import markdown_table
    from models.parallel import ProcessPool, usable_cores
    from models.trajectory.training import Budget, prepare, runs, train_and_save

    torch.set_num_threads(1)  # small nets; with 2 threads on a busy 2-core machine OpenMP contention made training ~10x slower
    p = training_plan(config)
    setup = prepare(tracks_20s, trajectory_modes, flights, flight_splits, weather, config.dt_s)
    todo = runs(p["algorithms"], p["discriminators"], p["seeds"])
    context.log.info(f"training {len(todo)} model bundles ({config.profile} profile: {p})")
    rows, t0 = [], time.perf_counter()
    folder = str(artifact_path("models/trajectory", ""))
    budget = Budget(p["bc_epochs"], p["gail_iterations"])
    jobs = [(setup, algorithm, scheme, seed, budget, disc, folder, config.profile) for algorithm, scheme, seed, disc in todo]
    # each bundle trains on one thread: the bundles share the cores as parallel processes
    with ProcessPool(config.workers or usable_cores(), train_and_save) as pool:
        for k, row in enumerate(pool.iter(jobs), 1):
            rows.append(row)
            context.log.info(f"[{k}/{len(todo)}] {row['name']}: {row['train_s']:.1f} s, final BC loss {row['final_bc_loss']:.3f}")
    catalogue = pl.DataFrame(rows, schema_overrides={"discriminator": pl.String})
    summary = catalogue.group_by("method", "scheme").agg(pl.len().alias("seeds"), pl.col("train_s").mean().round(1).alias("mean_train_s"))
    return dg.Output(catalogue, metadata={
        "bundles": len(rows), "train_s": round(time.perf_counter() - t0, 1), "profile": config.profile,
        "settings": dg.MetadataValue.json(p), "per_method": dg.MetadataValue.md(markdown_table(summary.sort("method", "scheme"))),
    })
