"""Route modalities and the train/test split: tracks_20s -> trajectory_modes -> flight_splits."""

import dagster as dg
import polars as pl
from pydantic import Field

from models.aviation.modes import date_separation, trajectory_modes as cluster_modes
from models.aviation.plots import dendrogram, silhouette_curve, tracks_map_by_mode
from models.aviation.recording import write_modes_recording
from models.aviation.split import split_flights
from warehouse.artifacts import artifact_path, save_plot


class ModesConfig(dg.Config):
    max_modes: int = Field(default=8, description="largest cluster count the silhouette search tries")
    min_flights: int = Field(default=3, description="a route with fewer flights gets a single mode")
    dtw_stride: int = Field(
        default=3, description="DTW on every n-th point of the constant-step tracks (3 = one point a minute at 20 s; 1 = all)"
    )
    reference_date: str | None = Field(
        default="2022-02-27",
        description="if set, metadata reports how well the whole-trajectory modes separate flights before/after "
        "this UTC date (purity of every mode, adjusted Rand index at two clusters); the bundled data's "
        "airspace closures fell on 2022-02-27",
    )


@dg.asset(group_name="aviation", description="Mode of every flight per phase and for the whole trajectory (phase = all).")
def trajectory_modes(context: dg.AssetExecutionContext, config: ModesConfig, tracks_20s: pl.DataFrame, flights: pl.DataFrame):
    modes, clusterings = cluster_modes(
        tracks_20s, flights, max_modes=config.max_modes, min_flights=config.min_flights, stride=config.dtw_stride
    )
    n_modes = {f"{route} {phase}": c.n_modes for (route, phase), c in clusterings.items()}
    context.log.info("modes per route and phase: " + ", ".join(f"{k}={v}" for k, v in n_modes.items()))
    metadata = {"n_modes": dg.MetadataValue.json(n_modes)}
    if config.reference_date:
        ref = pl.Series([config.reference_date]).str.to_datetime(time_zone="UTC")[0]
        sep = {route: date_separation(c, flights, ref) for (route, phase), c in clusterings.items() if phase == "all"}
        metadata["date_separation"] = dg.MetadataValue.json(sep)
        context.log.info(f"separation of flights before/after {config.reference_date}: {sep}")
    for name, png in [
        ("modes_map", tracks_map_by_mode(tracks_20s, modes, phase="all")),
        ("silhouette_curves", silhouette_curve(clusterings)),
    ] + [
        (f"dendrogram_{route}_{phase}", dendrogram(c, f"{route} {phase}"))
        for (route, phase), c in clusterings.items()
        if phase == "all" and c.linkage is not None
    ]:
        path, md = save_plot(name, png)
        metadata[name] = dg.MetadataValue.md(md)
    rrd = write_modes_recording(tracks_20s, modes, artifact_path("recordings", "trajectory_modes.rrd"))
    metadata["rerun_recording"] = dg.MetadataValue.path(str(rrd))
    context.log.info(f"rerun recording: rerun {rrd}")
    return dg.Output(modes, metadata=metadata)


class SplitConfig(dg.Config):
    test_fraction: float = Field(default=0.2, description="share of each route x mode held out for testing")
    seed: int = Field(default=0, description="seed of the split; the same seed gives the same split")


@dg.asset(group_name="aviation", description="Seeded train/test split by flight, stratified by route and mode.")
def flight_splits(config: SplitConfig, flights: pl.DataFrame, trajectory_modes: pl.DataFrame):
    splits = split_flights(flights, trajectory_modes, config.test_fraction, config.seed)
    return dg.Output(splits, metadata={"counts": dg.MetadataValue.json(dict(splits["split"].value_counts().rows()))})
