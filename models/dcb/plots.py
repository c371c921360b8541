"""Figures of the DCB system as PNG bytes (matplotlib object API, no pyplot state)."""

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from models.dcb.problem import REGULATED_MIN, DCBProblem
from models.figures import band, over_seeds, png_bytes

# Fig 5.7's colours (HCMARL blue, stHMIRL red, sHMIRL green, tHMIRL black) plus the two flat learners
COLORS = {"HCMARL": "#1f77b4", "stHMIRL": "#d62728", "sHMIRL": "#2ca02c", "tHMIRL": "#000000", "MIRL": "#9467bd", "CMARL": "#ff7f0e",
          "optimum": "#17becf", "FCFS": "#bcbd22", "readout_only": "#8c564b"}


def demand_vs_capacity(problem: DCBProblem, before: np.ndarray, after: np.ndarray, title: str) -> bytes:
    """Demand / capacity of every sector-hour with demand, before and after the delays (1 = at capacity)."""
    fig = Figure(figsize=(10, 4.5))
    axes = fig.subplots(1, 2, sharey=True)
    for ax, delay, label in zip(axes, (before, after), ("before delays", "after delays")):
        ev = problem.evaluate(delay, all_entries=True)
        key = np.nonzero(ev.counts)[0]
        ratio = ev.counts[key] / problem.capacity[key]
        hour, sector = key % problem.n_hours, key // problem.n_hours
        ax.scatter(hour + (sector / problem.n_sectors - 0.5) * 0.6, ratio, s=8, c=np.where(ratio > 1, "#d62728", "#1f77b4"))
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_title(f"{label}: {int(ev.hot.sum())} hotspots")
        ax.set_xlabel("hour of day (UTC)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("entries / capacity per sector-hour")
    fig.suptitle(title)
    return png_bytes(fig)


def delay_histogram(delays: pl.DataFrame, title: str) -> bytes:
    """Histogram of delays >= 4 min per method (all seeds pooled)."""
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    reg = delays.filter(pl.col("delay_min") >= REGULATED_MIN)
    bins = np.arange(REGULATED_MIN, max(int(reg["delay_min"].max() or REGULATED_MIN), REGULATED_MIN) + 3, 2)
    for (method,), g in reg.group_by("method", maintain_order=True):
        n_runs = delays.filter(pl.col("method") == method).select(pl.struct("case", "seed").n_unique()).item()
        ax.hist(g["delay_min"].to_numpy(), bins=bins, histtype="step", lw=1.5, label=method, color=COLORS.get(method, "#7f7f7f"),
                weights=np.full(g.height, 1.0 / n_runs))
    ax.set_xlabel(f"ground delay [min] (delays < {REGULATED_MIN} min not shown)")
    ax.set_ylabel("flights per run")
    ax.legend()
    ax.set_title(title)
    return png_bytes(fig)


def box_plots(results: pl.DataFrame, methods: list[str]) -> bytes:
    """Fig 5.7: (a) average delay per flight and (b) regulated flights, per case, box over seeds."""
    cases = results["case"].unique(maintain_order=True).to_list()
    fig = Figure(figsize=(max(7, 2.5 * len(cases) * len(methods) / 3), 7.5))
    axes = fig.subplots(2, 1)
    width = 0.8 / len(methods)
    for ax, metric, label in zip(axes, ("avg_delay_min", "regulated_flights"), ("(a) average delay per flight [min]", "(b) regulated flights")):
        for k, m in enumerate(methods):
            data = [results.filter((pl.col("case") == c) & (pl.col("method") == m))[metric].to_numpy() for c in cases]
            pos = np.arange(len(cases)) + (k - (len(methods) - 1) / 2) * width
            bp = ax.boxplot(data, positions=pos, widths=width * 0.9, manage_ticks=False, patch_artist=False)
            for part in ("boxes", "whiskers", "caps", "medians"):
                for line in bp[part]:
                    line.set_color(COLORS.get(m, "#7f7f7f"))
            ax.plot([], [], color=COLORS.get(m, "#7f7f7f"), label=m)
        ax.set_xticks(np.arange(len(cases)), cases)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(ncol=len(methods), fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0))
    return png_bytes(fig)


def learning_curves(curves: pl.DataFrame, episodes_per_level: int) -> bytes:
    """Per case, hotspots left and total delay of the training episodes (ε-greedy, every 50th) per learner, mean over
    seeds with the seeds' range; `curves` has case, method, seed, episode, hotspots_left, total_delay_min. Hierarchical
    learners train their abstract level first: its episodes are left of the dotted line."""
    cases = curves["case"].unique(maintain_order=True).to_list()
    fig = Figure(figsize=(11, 3.2 * len(cases)))
    axes = fig.subplots(len(cases), 2, squeeze=False)
    mean = over_seeds(curves, ["case", "method", "episode"], ("hotspots_left", "total_delay_min"))
    hierarchical = curves["episode"].max() >= episodes_per_level
    for row, case in zip(axes, cases):
        for (method,), g in mean.filter(pl.col("case") == case).group_by("method", maintain_order=True):
            g = g.sort("episode")
            for ax, col in zip(row, ("hotspots_left", "total_delay_min")):
                band(ax, g["episode"], g, col, COLORS.get(method, "#7f7f7f"), method)
        for ax, label in zip(row, ("hotspots left", "total delay [min]")):
            if hierarchical:
                ax.axvline(episodes_per_level, color="k", lw=0.8, ls=":")
            ax.set_title(f"{case}: {label} in training episodes")
            ax.set_xlabel("training episode (hierarchical learners: abstract level, then ground level after the dotted line)", fontsize=7)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, ncol=2)
    return png_bytes(fig)
