"""Figures of the urban system as PNG bytes (matplotlib object API, no pyplot state)."""

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from models.figures import band, over_seeds, png_bytes

METHOD_COLORS = {"col_marl": "#1f77b4", "i_marl": "#ff7f0e", "idm": "#2ca02c", "krauss": "#d62728", "ch3_dqn_cnn": "#9467bd"}
BIN_M = 10.0


def route_profiles(traj: pl.DataFrame, route: str) -> pl.DataFrame:
    """Mean speed and acceleration of the vehicles of `route` by distance travelled (10 m bins), per method.
    Distance = cumulative length of each vehicle's 1 s path (vectorised over all vehicles with polars)."""
    return (
        traj.filter(pl.col("route") == route)
        .sort("method", "vehicle_id", "t")
        .with_columns(
            step_m=((pl.col("x").diff() ** 2 + pl.col("y").diff() ** 2).sqrt()).over("method", "vehicle_id").fill_null(0.0)
        )
        .with_columns(dist_m=pl.col("step_m").cum_sum().over("method", "vehicle_id"))
        .with_columns(bin_m=(pl.col("dist_m") / BIN_M).floor() * BIN_M)
        .group_by("method", "bin_m")
        .agg(speed_mps=pl.col("speed_mps").mean(), accel_mps2=pl.col("accel_mps2").mean(), vehicles=pl.col("vehicle_id").n_unique())
        .sort("method", "bin_m")
    )


def route_profile_png(traj: pl.DataFrame, route: str, junctions_m: list[float], title: str) -> bytes:
    """Fig 4.4: average speed and acceleration along one route, learned policy against SUMO's drivers;
    dashed lines mark the junctions."""
    prof = route_profiles(traj, route)
    fig = Figure(figsize=(11, 4), dpi=100)
    axes = fig.subplots(1, 2)
    for (method,), g in prof.group_by("method", maintain_order=True):
        for ax, colname in zip(axes, ("speed_mps", "accel_mps2")):
            ax.plot(g["bin_m"], g[colname], label=method, color=METHOD_COLORS.get(method, "k"))
    for ax, label in zip(axes, ("average speed (m/s)", "average acceleration (m/s²)")):
        for j in junctions_m:
            ax.axvline(j, color="grey", ls="--", lw=0.8)
        ax.set_xlabel("distance along the route (m)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(title)
    return png_bytes(fig)


def busiest_route(traj: pl.DataFrame, method: str = "col_marl") -> str:
    counts = traj.filter(pl.col("method") == method).group_by("route").agg(pl.col("vehicle_id").n_unique().alias("n"))
    return counts.sort("n", "route", descending=[True, False])["route"][0]


def junction_offsets_m(edges: str, net_path: str) -> list[float]:
    """Distance from the route's start to each junction it crosses (ends of all edges but the last)."""
    from models.urban.network import read_net

    net = read_net(net_path)
    lengths = np.array([net.getEdge(e).getLength() for e in edges.split()])
    return list(np.cumsum(lengths)[:-1])


def training_curves_png(training: pl.DataFrame) -> bytes:
    """Learning curves of `urban_training`, a row per scenario: the mean return of the route agents that drove in the
    episode and their mean loss, per method, mean over seeds with the seeds' range, and ε (dotted, right axis)."""
    per_seed = training.group_by("scenario", "method", "seed", "episode").agg(
        pl.col("return").mean(), pl.col("loss").mean(), pl.col("epsilon").first())
    curves = over_seeds(per_seed, ["scenario", "method", "episode", "epsilon"], ("return", "loss")).sort("scenario", "method", "episode")
    scenarios = training["scenario"].unique(maintain_order=True).to_list()
    fig = Figure(figsize=(11, 3.4 * len(scenarios)), dpi=100)
    axes = fig.subplots(len(scenarios), 2, squeeze=False)
    for row, scenario in zip(axes, scenarios):
        one = curves.filter(pl.col("scenario") == scenario)
        for (method,), g in one.group_by("method", maintain_order=True):
            for ax, col in zip(row, ("return", "loss")):
                band(ax, g["episode"], g, col, METHOD_COLORS.get(method, "k"), method)
        eps = row[0].twinx()  # every method of a run shares the schedule: the first one's
        first = one.filter(pl.col("method") == one["method"][0])
        eps.plot(first["episode"], first["epsilon"], color="0.4", ls=":", lw=1)
        eps.set_ylabel("ε (dotted)")
        eps.set_ylim(0, 1)
        row[0].set_title(f"{scenario}: mean return of the route agents")
        row[1].set_title(f"{scenario}: DDQN loss")
        row[1].set_yscale("log")
        for ax in row:
            ax.set_xlabel("training episode")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    return png_bytes(fig)
