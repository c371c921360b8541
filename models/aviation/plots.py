"""Static figures of tracks, phases and route modes, as PNG bytes for Dagster metadata and reports.

Figures are built with matplotlib's object API (`Figure` + Agg canvas) rather than pyplot: no global
state, no GUI backend, safe inside a Dagster worker. Tracks are drawn as LineCollections built from
whole arrays (one segment per pair of consecutive points of a flight), not flight by flight.
"""

from __future__ import annotations

import base64
import io

import numpy as np
import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy.cluster.hierarchy import dendrogram as scipy_dendrogram

from models.units import M_PER_FT

DPI = 100
PHASE_COLORS = {"climb": "#2ca02c", "cruise": "#1f77b4", "descent": "#d62728"}
OTHER_COLOR = "#7f7f7f"  # points whose phase is unknown
# a fixed palette (tab10) so that mode k has the same colour in every figure and in the rerun recording
MODE_COLORS = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
)


def mode_color(k: int) -> str:
    return MODE_COLORS[int(k) % len(MODE_COLORS)]


def png_markdown(png: bytes, alt: str) -> str:
    """Markdown embedding the PNG inline (Dagster renders data: URIs in markdown metadata)."""
    return f"![{alt}](data:image/png;base64,{base64.b64encode(png).decode()})"


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _empty(fig: Figure, ax, message: str) -> bytes:
    ax.text(0.5, 0.5, message, ha="center", va="center", transform=ax.transAxes)
    ax.set_axis_off()
    return _png(fig)


def _segments(x: np.ndarray, y: np.ndarray, flight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(segments (m, 2, 2), index of each segment's first point) joining consecutive points of a flight.

    Points must be sorted by flight then time; pairs that straddle two flights are dropped.
    """
    same = flight[1:] == flight[:-1]
    start = np.flatnonzero(same)
    seg = np.stack([np.column_stack([x[start], y[start]]), np.column_stack([x[start + 1], y[start + 1]])], axis=1)
    return seg, start


# --------------------------------------------------------------------------------------------- altitude


def altitude_profiles_by_phase(tracks: pl.DataFrame) -> bytes:
    """Altitude vs minutes since each flight's first point; one faint line per flight, coloured by phase."""
    fig = _figure(10, 5)
    ax = fig.add_subplot()
    pts = tracks.select("flight_id", "ts", "alt_m", "phase").drop_nulls(["ts", "alt_m"]).sort("flight_id", "ts")
    if pts.height < 2:
        return _empty(fig, ax, "no tracks")
    pts = pts.with_columns(
        minutes=(pl.col("ts") - pl.col("ts").min().over("flight_id")).dt.total_microseconds() / 60e6
    )
    flight = pts["flight_id"].to_numpy()
    seg, start = _segments(pts["minutes"].to_numpy(), pts["alt_m"].to_numpy(), flight)
    phase = pts["phase"].fill_null("").to_numpy()[start]
    colors = np.full(len(start), OTHER_COLOR, dtype=object)
    for name, color in PHASE_COLORS.items():
        colors[phase == name] = color
    n_flights = int(np.unique(flight).size)
    alpha = float(np.clip(8.0 / max(n_flights, 1), 0.08, 0.8))  # fainter as flights pile up
    ax.add_collection(LineCollection(seg, colors=list(colors), linewidths=0.9, alpha=alpha))
    ax.autoscale_view()
    ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    ax.set_xlabel("time since first point [min]")
    ax.set_ylabel("barometric altitude [m]")
    fl = ax.secondary_yaxis("right", functions=(lambda m: m / M_PER_FT / 100, lambda f: f * 100 * M_PER_FT))
    fl.set_ylabel("flight level [FL, 100 ft]")
    ax.set_title(f"Altitude profiles by phase ({n_flights} flights)")
    ax.grid(alpha=0.3)
    handles = [Line2D([], [], color=c, lw=2, label=p) for p, c in PHASE_COLORS.items()]
    if (colors == OTHER_COLOR).any():
        handles.append(Line2D([], [], color=OTHER_COLOR, lw=2, label="unknown"))
    ax.legend(handles=handles, loc="upper right", title="phase")
    return _png(fig)


# --------------------------------------------------------------------------------------------- map


def tracks_map_by_mode(tracks: pl.DataFrame, modes_df: pl.DataFrame, phase: str = "all") -> bytes:
    """Lon/lat of every flight coloured by its mode for `phase`, one panel per route (no basemap).

    For a phase other than "all" only that phase's points are drawn (the sub-trajectory clustered).
    Each panel's aspect is 1/cos(mean latitude), so that a degree east and north look alike on paper.
    """
    m = modes_df.filter(pl.col("phase") == phase).select("flight_id", "route", "mode", "n_modes", "silhouette")
    pts = tracks.select("flight_id", "ts", "lat", "lon", "phase").drop_nulls(["lat", "lon"])
    if phase != "all":
        pts = pts.filter(pl.col("phase") == phase)
    pts = pts.join(m, on="flight_id", how="inner").sort("route", "flight_id", "ts")
    routes = pts["route"].unique().sort().to_list()
    ncols = min(len(routes), 3) or 1
    nrows = -(-len(routes) // ncols) or 1
    fig = _figure(5.5 * ncols, 4.8 * nrows)
    if not routes:
        return _empty(fig, fig.add_subplot(), f"no modes for phase '{phase}'")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[len(routes):]:
        ax.set_axis_off()
    for ax, route in zip(axes, routes):
        r = pts.filter(pl.col("route") == route)
        flight = r["flight_id"].to_numpy()
        seg, start = _segments(r["lon"].to_numpy(), r["lat"].to_numpy(), flight)
        mode = r["mode"].to_numpy()[start]
        ax.add_collection(
            LineCollection(seg, colors=[mode_color(k) for k in mode], linewidths=0.8, alpha=0.6)
        )
        ax.autoscale_view()
        ax.set_aspect(1.0 / np.cos(np.radians(float(r["lat"].mean()))), adjustable="datalim")
        per_mode = r.unique("flight_id").group_by("mode").len().sort("mode")
        handles = [
            Line2D([], [], color=mode_color(k), lw=2, label=f"mode {k} ({n} flights)")
            for k, n in per_mode.iter_rows()
        ]
        ax.legend(handles=handles, loc="best", fontsize="small")
        sil = r["silhouette"][0]
        sil_txt = f", silhouette {sil:.2f}" if sil is not None else ""
        ax.set_title(f"{route} – {phase}: {r['n_modes'][0]} mode(s){sil_txt}", fontsize="medium")
        ax.set_xlabel("longitude [°E]")
        ax.set_ylabel("latitude [°N]")
        ax.grid(alpha=0.3)
    fig.suptitle(f"Tracks coloured by route mode (phase: {phase})")
    return _png(fig)


# --------------------------------------------------------------------------------------------- clustering


def silhouette_curve(clusterings: dict) -> bytes:
    """Silhouette vs number of clusters for each (route, phase); the chosen k is marked with a star."""
    fig = _figure(8, 5)
    ax = fig.add_subplot()
    curves = {key: c for key, c in clusterings.items() if c.silhouette_curve}
    if not curves:
        return _empty(fig, ax, "no route with enough flights to score a clustering")
    for i, ((route, phase), c) in enumerate(sorted(curves.items())):
        ks = np.array(sorted(c.silhouette_curve))
        s = np.array([c.silhouette_curve[k] for k in ks])
        color = MODE_COLORS[i % len(MODE_COLORS)]
        ax.plot(ks, s, marker="o", ms=4, color=color, label=f"{route} {phase} (k={c.n_modes})")
        if c.silhouette is not None:
            ax.plot([c.n_modes], [c.silhouette], marker="*", ms=14, color=color, mec="black", mew=0.6, ls="none")
    ax.set_xlabel("number of clusters k")
    ax.set_ylabel("silhouette score [-]")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_title("Silhouette of the Ward/DTW clustering (★ = chosen k)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", ncols=2 if len(curves) > 6 else 1)
    return _png(fig)


def _node_modes(z: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Mode of every dendrogram node (leaves, then merges n, n+1, ...), -1 where it spans several modes."""
    n = len(z) + 1
    node = np.full(2 * n - 1, -1, dtype=np.int64)
    node[:n] = labels if len(labels) == n else -1
    for i, (a, b) in enumerate(z[:, :2].astype(np.int64)):  # one step per merge, children come first
        node[n + i] = node[a] if node[a] == node[b] else -1
    return node


def dendrogram(clustering, title: str, max_leaves: int = 40) -> bytes:
    """Ward dendrogram, links coloured by the chosen modes; truncated to `max_leaves` leaves for large n."""
    fig = _figure(10, 5)
    ax = fig.add_subplot()
    z = clustering.linkage
    if z is None or len(z) == 0:
        return _empty(fig, ax, f"{title}: nothing to cluster")
    n = len(z) + 1
    k = clustering.n_modes
    # any height between the merges that leave k and k-1 clusters cuts the tree into the chosen k modes
    cut = 0.5 * (z[-k, 2] + z[-(k - 1), 2]) if 1 < k < n else (z[-1, 2] * 1.01 if k <= 1 else 0.0)
    labels = list(clustering.flight_ids) if len(clustering.flight_ids) == n and n <= max_leaves else None
    node_mode = _node_modes(z, np.asarray(clustering.labels))
    scipy_dendrogram(
        z,
        ax=ax,
        # the same colour per mode as in the map and the rerun recording; grey above the cut
        link_color_func=lambda node: mode_color(node_mode[node]) if node_mode[node] >= 0 else "#555555",
        labels=labels,
        truncate_mode="lastp" if n > max_leaves else None,
        p=max_leaves,
        leaf_rotation=90,
        leaf_font_size=7,
        show_contracted=True,
    )
    if 1 < k < n:
        ax.axhline(cut, color="black", ls="--", lw=0.8, label=f"cut into {k} modes")
        ax.legend(loc="upper right")
    ax.set_ylabel("Ward merge height [normalised DTW]")
    ax.set_xlabel("flights" if labels else "flights (leaf counts in brackets)")
    ax.set_title(f"Dendrogram – {title} ({n} flights)")
    return _png(fig)
