"""Route modalities (thesis §7.4.1): agglomerative clustering of (sub-)trajectories with DTW.

Flights of one origin-destination pair do not all fly the same way: airspace closures, runway
configurations and ATC routings create a few distinct *modes*. The thesis finds them by clustering the
trajectories, on (lon, lat, alt) only, with

    dist(Li, Lj) = DTW(Li, Lj) / sqrt(d * L),    d = 3,  L = max(|Li|, |Lj|)      (Eq 7.4)

Ward linkage, and the number of clusters that maximises the silhouette. DTW here is dtaidistance's
multivariate (dependent) DTW: the square root of the summed squared Euclidean point distances along the
optimal warping path, so dividing by sqrt(d * L) turns it into an RMS per coordinate and per step, i.e.
comparable between short and long flights.

Scaling: degrees and metres are not comparable, so before DTW each of lon, lat, alt is min-max scaled to
[0, 1] over *all points of the set being clustered* (one route and one phase at a time). A single
transform for the whole set keeps distances between trajectories meaningful (scaling each flight on its
own would erase exactly the offsets we want to find); the cost is that a variable with a small spread
within the set (e.g. latitude on an east-west route) is stretched as much as one with a large spread.

Clustering runs per route (a mode is a way of flying *that* route) for the whole trajectory
(phase "all") and for each phase's sub-trajectory (climb, cruise, descent).

Resolution: DTW costs O(L^2) per pair, and a mode is a route-scale shape (modes differ by tens of NM), so
the distances use every `stride`-th point of the constant-step tracks (default 3: one point a minute at
20 s, ~8 NM apart at cruise speed), which cuts the DP cells ninefold. The DTW itself stays exact;
stride=1 uses every point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime

import numpy as np
import polars as pl
from dtaidistance import dtw_ndim
from scipy.cluster.hierarchy import fcluster, linkage as hier_linkage
from scipy.spatial.distance import squareform
from sklearn.metrics import adjusted_rand_score, silhouette_score
from sklearn.metrics.cluster import contingency_matrix

from models.aviation.phases import PHASES

ALL = "all"
FEATURES = ("lon", "lat", "alt_m")  # the thesis clusters on position only, not speed or time
MIN_POINTS = 2  # a (sub-)trajectory needs at least two points to be a trajectory

MODES_SCHEMA = {
    "flight_id": pl.String,
    "route": pl.String,
    "phase": pl.String,
    "mode": pl.Int64,
    "n_modes": pl.Int64,
    "silhouette": pl.Float64,
}


# --------------------------------------------------------------------------------------------- distances


def pairwise_dtw(series: list[np.ndarray], window: int | None = None) -> np.ndarray:
    """Exact multivariate DTW of every pair, condensed (scipy order: i < j, row by row).

    Runs dtaidistance's C code in parallel (OpenMP) with `use_pruning`: each pair is bounded by the
    cost of one warping path (diagonal, then the longer tail against the last point of the shorter
    series) and DP cells above the bound are abandoned, about 1.3x faster on flight tracks.

    Why the second pass: in dtaidistance 2.5.1 that bound is wrong for series of *different lengths*
    in the n-dimensional code (the tail compares every coordinate with the first coordinate of the
    last point, so it can undercut the true DTW), and a pair whose DTW equals the bound can fail the
    check by a rounding error. Either way the pair comes back as +inf, never as a wrong finite value
    (a finite result is the cost of a real path below the bound, hence the optimum). So the +inf pairs,
    typically a few to 20 %, are recomputed without pruning: the matrix is exact DTW.
    """
    n = len(series)
    arrs = [np.ascontiguousarray(s, dtype=np.float64) for s in series]
    ndim = arrs[0].shape[1]
    condensed = np.asarray(
        dtw_ndim.distance_matrix(
            arrs, ndim=ndim, compact=True, parallel=True, use_c=True, use_pruning=True, window=window
        ),
        dtype=np.float64,
    )
    redo = np.flatnonzero(~np.isfinite(condensed))
    if redo.size:
        i, j = np.triu_indices(n, k=1)
        # a loop over pairs (not points); each call is a full C DTW
        condensed[redo] = [dtw_ndim.distance(arrs[i[k]], arrs[j[k]], use_c=True, window=window) for k in redo]
    if not np.isfinite(condensed).all():
        raise ValueError("DTW is infinite for some pairs: is `window` narrower than their length difference?")
    return condensed


def normalised_dtw_matrix(series: list[np.ndarray], window: int | None = None) -> np.ndarray:
    """Square matrix of DTW(Li, Lj) / sqrt(d * max(|Li|, |Lj|)) (Eq 7.4) for (L_i, d) arrays already scaled.

    Exact DTW by default. `window` (Sakoe-Chiba band, in steps) is *not* exact: it forbids warping more
    than `window` steps off the diagonal, so distances can only grow. Only worth it for sets far larger
    than a route's flights: on 1,000 sub-trajectories of 150-300 points, window=30 (10 min at 20 s)
    halved the time, raised 28 % of the distances (median +2 %, max +119 %) and gave the same clusters.
    """
    n = len(series)
    if n < 2:
        return np.zeros((n, n))
    ndim = np.asarray(series[0]).shape[1]
    condensed = pairwise_dtw(series, window)
    lengths = np.fromiter((len(s) for s in series), dtype=np.float64, count=n)
    i, j = np.triu_indices(n, k=1)
    condensed /= np.sqrt(ndim * np.maximum(lengths[i], lengths[j]))
    return squareform(condensed, checks=False)


def minmax_scale(x: np.ndarray) -> np.ndarray:
    """Each column to [0, 1] over all rows; a constant column becomes 0 (nothing to tell apart)."""
    lo = x.min(axis=0)
    span = x.max(axis=0) - lo
    return (x - lo) / np.where(span > 0, span, 1.0)


# --------------------------------------------------------------------------------------------- clustering


@dataclass
class ModeClustering:
    """One dendrogram and the cut chosen by silhouette.

    labels: 0-based mode per series, renumbered by cluster size (0 = largest).
    silhouette: score of the chosen cut; None when no cut could be scored (fewer than 3 series).
    silhouette_curve: k -> silhouette for every k tried.
    linkage: scipy linkage matrix (n-1, 4); None when not clustered (n < 2, or fewer than min_flights).
    flight_ids: the flight of each series, in the order of `labels` (empty if clustered anonymously).
    """

    labels: np.ndarray
    n_modes: int
    silhouette: float | None
    silhouette_curve: dict[int, float]
    linkage: np.ndarray | None
    flight_ids: tuple[str, ...] = field(default=())


def _by_size(raw: np.ndarray) -> np.ndarray:
    """Renumber cluster labels 0..k-1 by decreasing size (ties: smaller original label first)."""
    if raw.size == 0:
        return raw.astype(np.int64)
    uniq, inverse, counts = np.unique(raw, return_inverse=True, return_counts=True)
    order = np.lexsort((uniq, -counts))  # primary key: size descending
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return rank[inverse].astype(np.int64)


def _single_mode(n: int, z: np.ndarray | None = None, ids: tuple[str, ...] = ()) -> ModeClustering:
    return ModeClustering(np.zeros(n, dtype=np.int64), 1 if n else 0, None, {}, z, ids)


def cluster_distances(
    dist: np.ndarray, max_modes: int = 8, min_modes: int = 2, ids: tuple[str, ...] = ()
) -> ModeClustering:
    """Ward dendrogram of a precomputed square distance matrix, cut where the silhouette is highest."""
    n = dist.shape[0]
    if n < 2:
        return _single_mode(n, None, ids)
    z = hier_linkage(squareform(dist, checks=False), method="ward")
    if n < 3:  # a silhouette needs 2 <= k <= n - 1
        return _single_mode(n, z, ids)
    curve: dict[int, float] = {}
    for k in range(max(min_modes, 2), min(max_modes, n - 1) + 1):
        labels = fcluster(z, k, criterion="maxclust")
        # ties in merge heights can give fewer than k clusters: that cut is scored under its own k
        if np.unique(labels).size != k:
            continue
        curve[k] = float(silhouette_score(dist, labels, metric="precomputed"))
    if not curve:
        return _single_mode(n, z, ids)
    best = max(curve, key=lambda k: (curve[k], -k))  # highest score, the fewer modes on a tie
    labels = _by_size(fcluster(z, best, criterion="maxclust"))
    return ModeClustering(labels, int(np.unique(labels).size), curve[best], curve, z, ids)


def cluster_series(
    series: list[np.ndarray], max_modes: int = 8, min_modes: int = 2, ids: tuple[str, ...] = ()
) -> ModeClustering:
    """Cluster scaled (L_i, 3) series: normalised DTW, Ward linkage, k by silhouette in [min_modes, max_modes]."""
    return cluster_distances(normalised_dtw_matrix(series), max_modes, min_modes, ids)


def cut(clustering: ModeClustering, k: int) -> np.ndarray:
    """Labels (0-based, by size) of the same dendrogram cut into at most k clusters."""
    if clustering.linkage is None or k <= 1:
        return np.zeros(len(clustering.labels), dtype=np.int64)
    return _by_size(fcluster(clustering.linkage, k, criterion="maxclust"))


def mode_purity(labels: np.ndarray, truth: np.ndarray) -> float:
    """Minimum over modes of the share of the mode's majority class (1.0 = every mode is pure)."""
    c = contingency_matrix(truth, labels)  # classes x modes
    return float((c.max(axis=0) / c.sum(axis=0)).min())


def mode_ari(labels: np.ndarray, truth: np.ndarray) -> float:
    """Adjusted Rand index between modes and a reference partition (sklearn)."""
    return float(adjusted_rand_score(truth, labels))


def date_separation(clustering: ModeClustering, flights: pl.DataFrame, reference: datetime) -> dict:
    """How well modes separate flights that started before vs after `reference` (UTC).

    Returns JSON-friendly numbers: purity of the chosen modes, ARI of the chosen modes and of the cut
    at two clusters, with the class sizes.
    """
    ids = pl.DataFrame({"flight_id": list(clustering.flight_ids)}, schema={"flight_id": pl.String})
    ts = ids.join(flights.select("flight_id", "first_ts"), on="flight_id", how="left", maintain_order="left")
    truth = (ts["first_ts"] >= reference).fill_null(False).to_numpy().astype(np.int64)
    out = {
        "n_flights": int(truth.size),
        "n_after": int(truth.sum()),
        "n_modes": int(clustering.n_modes),
    }
    if truth.size == 0:
        return out
    two = cut(clustering, 2)
    out |= {
        "purity": round(mode_purity(clustering.labels, truth), 4),
        "ari": round(mode_ari(clustering.labels, truth), 4),
        "purity_at_2": round(mode_purity(two, truth), 4),
        "ari_at_2": round(mode_ari(two, truth), 4),
    }
    return out


# --------------------------------------------------------------------------------------------- per route


def _scaled_series(points: pl.DataFrame) -> tuple[tuple[str, ...], list[np.ndarray]]:
    """(flight ids, one scaled (L, 3) array per flight) from points sorted by flight_id, ts."""
    runs = points.group_by("flight_id", maintain_order=True).len()
    x = minmax_scale(points.select(FEATURES).to_numpy().astype(np.float64))
    # rows of a C-contiguous array: every piece is itself C-contiguous, as dtaidistance wants
    pieces = np.split(np.ascontiguousarray(x), np.cumsum(runs["len"].to_numpy())[:-1])
    return tuple(runs["flight_id"].to_list()), pieces


def trajectory_modes(
    tracks: pl.DataFrame, flights: pl.DataFrame, max_modes: int = 8, min_flights: int = 3, stride: int = 3
) -> tuple[pl.DataFrame, dict[tuple[str, str], ModeClustering]]:
    """Mode of every flight, per route, for the whole trajectory (phase "all") and per phase.

    A route with fewer than `min_flights` flights (for that phase) gets a single mode 0 without a
    silhouette. A flight with fewer than two points in a phase gets no row for that phase. DTW uses
    every `stride`-th point of each flight (see the module docstring).
    Returns the table (columns of MODES_SCHEMA) and the clusterings by (route, phase).
    """
    pts = (
        tracks.select("flight_id", "ts", *FEATURES, "phase")
        .drop_nulls([*FEATURES])
        .join(flights.select("flight_id", "route"), on="flight_id", how="inner")
        .sort("flight_id", "ts")
        .filter(pl.int_range(pl.len()).over("flight_id") % max(stride, 1) == 0)
    )
    rows: list[pl.DataFrame] = []
    clusterings: dict[tuple[str, str], ModeClustering] = {}
    for route in sorted(pts["route"].unique().drop_nulls().to_list()):
        on_route = pts.filter(pl.col("route") == route)
        for phase in (ALL, *PHASES):
            sub = on_route if phase == ALL else on_route.filter(pl.col("phase") == phase)
            sub = sub.filter(pl.len().over("flight_id") >= MIN_POINTS)
            if sub.height == 0:
                continue
            ids, series = _scaled_series(sub)
            if len(ids) < min_flights:
                c = _single_mode(len(ids), None, ids)
            else:
                c = cluster_series(series, max_modes=max_modes, ids=ids)
            clusterings[(route, phase)] = c
            rows.append(
                pl.DataFrame(
                    {
                        "flight_id": list(ids),
                        "route": route,
                        "phase": phase,
                        "mode": c.labels,
                        "n_modes": c.n_modes,
                        "silhouette": c.silhouette,
                    },
                    schema=MODES_SCHEMA,
                )
            )
    modes = pl.concat(rows) if rows else pl.DataFrame(schema=MODES_SCHEMA)
    return modes, clusterings
