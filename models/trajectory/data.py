"""Expert demonstrations from the foundation tables: sub-trajectories per phase (MMIL) or whole (SMIL).

A demonstration set holds, for one phase ("climb", "cruise", "descent" or "all"), every flight's
sub-trajectory as (lon deg, lat deg, alt m) points at the constant track step, its start time, its
route and its mode. Modes are clustered per route, so a "global mode" numbers the (route, mode)
pairs of the phase's *training* flights: one policy mixture per phase covers both routes, and a flight
only ever chooses among its own route's modes. Each global mode has a goal: the mean end point of its
training sub-trajectories (§7.3: the phase's goal region is a 10 km circle around it). A test flight
keeps its cluster's mode when that cluster has training flights, else it is labelled with the nearest
training mode of its route, so nothing a model learns (modes, goals) comes from a test flight.
"""

from dataclasses import dataclass

import numpy as np
import polars as pl

from models.aviation.phases import PHASES

MODE_MATCH_POINTS = 20  # time-normalised points compared when a test flight is matched to a training mode
KM_PER_DEG = 111.195


class TrajectoryDataError(ValueError):
    """The input tables cannot form demonstrations (message names the table/column)."""


@dataclass
class Demonstrations:
    phase: str
    flight_ids: list[str]
    routes: list[str]
    modes: np.ndarray  # (N,) global mode per flight
    points: list[np.ndarray]  # N arrays of (n_i, 3) lon, lat, alt_m
    start_s: np.ndarray  # (N,) epoch seconds of the first point
    mode_keys: list[tuple[str, int]]  # global mode -> (route, mode within route)
    goals: np.ndarray  # (M, 3) lon, lat, alt_m: mean end point per global mode (training flights)

    @property
    def n_modes(self) -> int:
        return len(self.mode_keys)

    def route_modes(self, route: str) -> list[int]:
        return [g for g, (r, _) in enumerate(self.mode_keys) if r == route]

    def subset(self, keep: np.ndarray) -> "Demonstrations":
        idx = np.flatnonzero(keep)
        return Demonstrations(
            self.phase,
            [self.flight_ids[i] for i in idx],
            [self.routes[i] for i in idx],
            self.modes[idx],
            [self.points[i] for i in idx],
            self.start_s[idx],
            self.mode_keys,
            self.goals,
        )


def _require(df: pl.DataFrame, table: str, columns: tuple[str, ...]) -> None:
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise TrajectoryDataError(f"table {table}: missing column(s) {', '.join(missing)}")


def demonstrations(
    tracks: pl.DataFrame, modes: pl.DataFrame, flights: pl.DataFrame, splits: pl.DataFrame, phase: str
) -> tuple[Demonstrations, Demonstrations]:
    """(train, test) demonstrations of one phase; goals come from the training flights only."""
    _require(tracks, "tracks_20s", ("flight_id", "ts", "lon", "lat", "alt_m", "phase"))
    _require(modes, "trajectory_modes", ("flight_id", "phase", "mode"))
    _require(flights, "flights", ("flight_id", "route"))
    _require(splits, "flight_splits", ("flight_id", "split"))
    pts = tracks if phase == "all" else tracks.filter(pl.col("phase") == phase)
    labels = (
        modes.filter(pl.col("phase") == phase)
        .select("flight_id", "mode")
        .join(flights.select("flight_id", "route"), on="flight_id")
        .join(splits.select("flight_id", "split"), on="flight_id")
    )
    if labels.is_empty():
        raise TrajectoryDataError(f"table trajectory_modes: no flight has a mode for phase '{phase}'")
    pts = pts.join(labels, on="flight_id").sort("flight_id", "ts")
    grouped = pts.group_by("flight_id", maintain_order=True).agg(
        pl.col("route").first(), pl.col("mode").first(), pl.col("split").first(),
        pl.col("ts").first().dt.epoch("us").alias("start_us"),
        pl.col("lon"), pl.col("lat"), pl.col("alt_m"), pl.len().alias("n"),
    ).filter(pl.col("n") >= 3)
    points = [np.stack([np.asarray(a), np.asarray(b), np.asarray(c)], axis=1) for a, b, c in zip(grouped["lon"], grouped["lat"], grouped["alt_m"])]
    is_train = (grouped["split"] == "train").to_numpy()
    if not is_train.any():
        raise TrajectoryDataError(f"table flight_splits: no training flight has a '{phase}' sub-trajectory")
    keys = list(zip(grouped["route"].to_list(), grouped["mode"].to_list()))
    # the modes a model learns are the training flights' (route, mode) pairs; a test flight of a cluster without
    # training flights is labelled with its route's nearest training mode (else its goal would come from test flights)
    mode_keys = sorted({k for k, train in zip(keys, is_train) if train})
    key_index = {k: g for g, k in enumerate(mode_keys)}
    gmode = np.array([key_index.get(k, -1) for k in keys], dtype=np.int64)
    if (gmode < 0).any():
        gmode[gmode < 0] = nearest_training_mode(points, grouped["route"].to_list(), gmode, is_train, mode_keys, phase)
    ends = np.stack([p[-1] for p in points])
    goals = np.stack([ends[is_train & (gmode == g)].mean(axis=0) for g in range(len(mode_keys))])
    demos = Demonstrations(
        phase, grouped["flight_id"].to_list(), grouped["route"].to_list(), gmode, points,
        grouped["start_us"].to_numpy() / 1e6, mode_keys, goals,
    )
    return demos.subset(is_train), demos.subset(~is_train)


def time_normalised(values: np.ndarray, lengths: np.ndarray, n: int) -> np.ndarray:
    """Consecutive series (rows of `values`, `lengths` rows each) at n points equidistant in normalised time: (N, n, ...)."""
    offsets = np.cumsum(lengths) - lengths
    return values[offsets[:, None] + np.round(np.linspace(0.0, 1.0, n) * (lengths[:, None] - 1)).astype(np.int64)]


def nearest_training_mode(points: list[np.ndarray], routes: list[str], gmode: np.ndarray, is_train: np.ndarray,
                          mode_keys: list[tuple[str, int]], phase: str) -> np.ndarray:
    """For the flights with gmode -1 (a cluster without training flights): the training mode of the same route
    whose mean trajectory is nearest (RMS over time-normalised points)."""
    xyz = time_normalised(np.concatenate(points), np.array([len(p) for p in points]), MODE_MATCH_POINTS)
    shapes = xyz * [KM_PER_DEG * np.cos(np.radians(xyz[..., 1].mean())), KM_PER_DEG, 1e-3]  # east, north, up km
    means = np.stack([shapes[is_train & (gmode == g)].mean(axis=0) for g in range(len(mode_keys))])
    todo = np.flatnonzero(gmode < 0)
    same_route = np.asarray(routes)[todo][:, None] == np.array([r for r, _ in mode_keys])[None]
    lonely = todo[~same_route.any(axis=1)]
    if len(lonely):
        raise TrajectoryDataError(f"phase '{phase}': route {routes[lonely[0]]} has test flights but no training flight")
    rms = np.sqrt(((shapes[todo, None] - means[None]) ** 2).sum(-1).mean(-1))
    return np.where(same_route, rms, np.inf).argmin(axis=1)


def expert_pairs(demos: Demonstrations) -> tuple[np.ndarray, ...]:
    """Flattened expert (position, step index, action, global mode, start epoch s, own end point) over every step.

    position = (lon, lat, alt_m) before the step; action = (Δlon, Δlat, Δalt) of that step (Eq 7.1-7.3).
    The time step is the tracks' constant step, so elapsed = step index × dt is filled by the caller.
    """
    pos = np.concatenate([p[:-1] for p in demos.points])
    act = np.concatenate([np.diff(p, axis=0) for p in demos.points])
    step = np.concatenate([np.arange(len(p) - 1) for p in demos.points])
    mode = np.concatenate([np.full(len(p) - 1, m) for p, m in zip(demos.points, demos.modes)])
    start = np.concatenate([np.full(len(p) - 1, s) for p, s in zip(demos.points, demos.start_s)])
    end = np.concatenate([np.repeat(p[-1:], len(p) - 1, axis=0) for p in demos.points])
    return pos, step, act, mode, start, end


def per_route(demos: Demonstrations) -> Demonstrations:
    """The same demonstrations with one mode per route (for the mode-agnostic BC): goal = the route's mean end."""
    routes = sorted(set(demos.routes))
    modes = np.array([routes.index(r) for r in demos.routes], dtype=np.int64)
    ends = np.stack([p[-1] for p in demos.points])
    goals = np.stack([ends[modes == k].mean(axis=0) for k in range(len(routes))])
    return Demonstrations(demos.phase, demos.flight_ids, demos.routes, modes, demos.points, demos.start_s,
                          [(r, 0) for r in routes], goals)
