"""The heading-action flight environment of thesis chapter 6 (§6.4.1, Eq 6.4), stepping many flights at once.

An agent picks one of L_a discrete headings θ_k found from the expert data; the aircraft then moves

    lon_{t+1} = lon_t + cos(θ_k) · Δlon,   lat_{t+1} = lat_t + sin(θ_k) · Δlat          (Eq 6.4)

with Δlon, Δlat the mean absolute step of the expert tracks (θ is measured in that scaled frame: 0 = east,
90° = north). The altitude comes from a small regression net on (lon, lat) (NN_altitude: 50 ReLU), and the
weather (temperature, u, v) is interpolated at the new position from the GAIL environment's WeatherCube (the
foundation's sample_weather evaluated once on a grid at the experts' median time, read by trilinear
interpolation: the bundled GFS file has a single time, and a per-step polars lookup dominated the run time). An episode ends with success within
`goal_radius_km` of the destination, with failure outside the bounding box or after `max_steps` steps.

Everything is a numpy array over the N trajectories of the batch; nothing loops over trajectories.
"""

from dataclasses import asdict, dataclass

import numpy as np
import polars as pl
import torch

from models.trajectory.data import TrajectoryDataError, time_normalised
from models.trajectory.env import WeatherCube
from models.trajectory.metrics import haversine_km, matched_errors

RUNNING, SUCCESS, OUT_OF_BOX, STEP_LIMIT = 0, 1, 2, 3
# raw observation columns every learner maps to its own features
OBS_COLUMNS = ("lon_deg", "lat_deg", "alt_m", "elapsed_s", "temperature_k", "wind_u_mps", "wind_v_mps")
WEATHER_COLUMNS = ("temperature_k", "wind_u_mps", "wind_v_mps")
WEATHER_MARGIN_DEG = 5.0  # weather grid kept around the bounding box (one or two grid cells of GFS/ERA5)


@dataclass(frozen=True)
class HeadingGeometry:
    """Everything the MDP takes from the expert flights: actions, step sizes, goal, box, limits."""

    headings_rad: tuple[float, ...]  # θ_k in the (Δlon, Δlat)-scaled frame, 0 = east, counter-clockwise
    step_lon_deg: float  # Δlon: mean |lon_{t+1} - lon_t| of the expert tracks
    step_lat_deg: float  # Δlat
    goal_lon: float  # destination: median end point of the expert tracks (coverage stops before the airport)
    goal_lat: float
    bbox: tuple[float, float, float, float]  # lon_min, lon_max, lat_min, lat_max
    goal_radius_km: float = 5.0
    max_steps: int = 2000
    dt_s: float = 20.0
    weather_time_us: int = 0  # the experts' median time (µs since the epoch): when the weather is read

    def to_dict(self) -> dict:
        return asdict(self)


def fit_geometry(
    tracks: pl.DataFrame, n_headings: int = 4, goal_radius_km: float = 5.0, max_steps: int = 2000,
    bbox_margin_deg: float = 1.0, heading_coverage: float = 0.95,
) -> HeadingGeometry:
    """Headings (from the directions of the expert steps), step sizes, goal and bounding box.

    `tracks`: constant-step expert tracks (flight_id, ts, lon, lat), like `tracks_20s`.
    """
    tracks = check_tracks(tracks, ("flight_id", "ts", "lon", "lat"))
    steps = tracks.select(
        dlon=pl.col("lon").diff().over("flight_id"), dlat=pl.col("lat").diff().over("flight_id"),
        dt=pl.col("ts").diff().over("flight_id").dt.total_seconds(),
    ).drop_nulls()
    step_lon, step_lat = float(steps["dlon"].abs().mean()), float(steps["dlat"].abs().mean())
    # Direction of every expert step in the scaled frame. The L_a headings are evenly spaced quantiles of the
    # steps' deviation from their mean direction, the outer two bounding the central `heading_coverage` share:
    # a fan over the experts' directions, so that the agent can steer left and right of the route and even a
    # random policy progresses along it. A route that turns needs the tails: with the central 75 % ((k + ½)/4,
    # the earlier rule), UUEE-UMKK mode 0's final leg (SSE, steps at -74° median) had no heading east of
    # south, and following the route could not reach the goal.
    ang = np.arctan2(steps["dlat"].to_numpy() / step_lat, steps["dlon"].to_numpy() / step_lon)
    mean = np.arctan2(np.sin(ang).mean(), np.cos(ang).mean())
    deviation = np.angle(np.exp(1j * (ang - mean)))  # wrapped to (-π, π]
    headings = mean + np.quantile(deviation, np.linspace(0.5 - heading_coverage / 2, 0.5 + heading_coverage / 2, n_headings))
    ends = tracks.group_by("flight_id").agg(pl.col("lon").last(), pl.col("lat").last())
    goal_lon, goal_lat = float(ends["lon"].median()), float(ends["lat"].median())
    bbox = (
        min(float(tracks["lon"].min()), goal_lon) - bbox_margin_deg, max(float(tracks["lon"].max()), goal_lon) + bbox_margin_deg,
        min(float(tracks["lat"].min()), goal_lat) - bbox_margin_deg, max(float(tracks["lat"].max()), goal_lat) + bbox_margin_deg,
    )
    return HeadingGeometry(
        tuple(float(h) for h in headings), step_lon, step_lat, goal_lon, goal_lat, bbox,
        goal_radius_km, max_steps, float(steps["dt"].median()), int(tracks["ts"].dt.epoch("us").median()),
    )


def check_tracks(tracks: pl.DataFrame, columns: tuple[str, ...]) -> pl.DataFrame:
    """The tracks sorted by flight and time, or a one-line TrajectoryDataError naming what is missing."""
    missing = [c for c in columns if c not in tracks.columns]
    if missing:
        raise TrajectoryDataError(f"expert tracks lack columns {missing} (expected a tracks_20s-like table)")
    if tracks.height == 0 or tracks["flight_id"].n_unique() < 1:
        raise TrajectoryDataError("expert tracks are empty: no flight to learn from")
    short = tracks.group_by("flight_id").len().filter(pl.col("len") < 2)
    if short.height:
        raise TrajectoryDataError(f"expert flights need >= 2 points; {short.height} have fewer, e.g. {short['flight_id'][0]}")
    return tracks.sort("flight_id", "ts")


def expert_observations(tracks: pl.DataFrame) -> np.ndarray:
    """The expert tracks as environment observations (rows follow OBS_COLUMNS), in flight/time order."""
    tracks = check_tracks(tracks, ("flight_id", "ts", "lon", "lat", "alt_m", *WEATHER_COLUMNS))
    elapsed = (pl.col("ts") - pl.col("ts").first().over("flight_id")).dt.total_seconds(fractional=True)
    return tracks.select("lon", "lat", "alt_m", elapsed.alias("elapsed_s"), *WEATHER_COLUMNS).to_numpy().astype(np.float64)


class AltitudeNet(torch.nn.Module):
    """NN_altitude (§6.5.2): (lon, lat) -> altitude, one hidden layer of 50 ReLU; z-scored in and out."""

    def __init__(self, hidden: int = 50):
        super().__init__()
        self.net = torch.nn.Sequential(torch.nn.Linear(2, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 1))
        self.register_buffer("x_mean", torch.zeros(2))
        self.register_buffer("x_std", torch.ones(2))
        self.register_buffer("y_mean", torch.zeros(()))
        self.register_buffer("y_std", torch.ones(()))

    def forward(self, lon_lat: torch.Tensor) -> torch.Tensor:
        return self.net((lon_lat - self.x_mean) / self.x_std).squeeze(-1) * self.y_std + self.y_mean

    @torch.no_grad()
    def predict(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.stack([lon, lat], axis=1), dtype=torch.float32)
        return self(x).double().numpy()


def fit_altitude_net(tracks: pl.DataFrame, hidden: int = 50, epochs: int = 300, lr: float = 1e-2, seed: int = 0) -> AltitudeNet:
    """Train NN_altitude on the expert (lon, lat) -> alt_m pairs: full-batch Adam on the MSE."""
    torch.manual_seed(seed)
    x = torch.as_tensor(tracks.select("lon", "lat").to_numpy(), dtype=torch.float32)
    y = torch.as_tensor(tracks["alt_m"].to_numpy().copy(), dtype=torch.float32)
    model = AltitudeNet(hidden)
    model.x_mean.copy_(x.mean(0)), model.x_std.copy_(x.std(0).clamp_min(1e-6))
    model.y_mean.copy_(y.mean()), model.y_std.copy_(y.std().clamp_min(1.0))
    optimiser = torch.optim.Adam(model.parameters(), lr=lr)
    for _ in range(epochs):
        optimiser.zero_grad()
        loss = torch.nn.functional.mse_loss((model(x) - model.y_mean) / model.y_std, (y - model.y_mean) / model.y_std)
        loss.backward()
        optimiser.step()
    return model.eval()


def crop_weather(weather: pl.DataFrame, bbox: tuple[float, float, float, float]) -> pl.DataFrame:
    """The weather grid around the box: sample_weather rebuilds its grid on every call, so keep it small."""
    lon_min, lon_max, lat_min, lat_max = bbox
    m = WEATHER_MARGIN_DEG
    cropped = weather.filter(pl.col("lon").is_between(lon_min - m, lon_max + m) & pl.col("lat").is_between(lat_min - m, lat_max + m))
    if cropped.height == 0:
        raise TrajectoryDataError(f"the weather grid does not cover the flights' box lon {lon_min:.1f}..{lon_max:.1f}, lat {lat_min:.1f}..{lat_max:.1f}")
    return cropped


@dataclass
class StartStates:
    """Initial states of N trajectories: position and UTC time (µs since the epoch)."""

    lon: np.ndarray
    lat: np.ndarray
    alt_m: np.ndarray
    ts_us: np.ndarray

    @classmethod
    def first_points(cls, tracks: pl.DataFrame) -> "StartStates":
        """The first point of every flight of a tracks table, in flight_id order."""
        first = tracks.sort("flight_id", "ts").group_by("flight_id", maintain_order=True).first()
        return cls(first["lon"].to_numpy(), first["lat"].to_numpy(), first["alt_m"].to_numpy(), first["ts"].dt.epoch("us").to_numpy())

    @classmethod
    def all_points(cls, tracks: pl.DataFrame) -> "StartStates":
        """Every point of a tracks table as a possible start."""
        return cls(tracks["lon"].to_numpy(), tracks["lat"].to_numpy(), tracks["alt_m"].to_numpy(), tracks["ts"].dt.epoch("us").to_numpy())

    @classmethod
    def concat(cls, parts: list["StartStates"]) -> "StartStates":
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("lon", "lat", "alt_m", "ts_us")))

    def take(self, rows: np.ndarray) -> "StartStates":
        return StartStates(self.lon[rows], self.lat[rows], self.alt_m[rows], self.ts_us[rows])

    def __len__(self) -> int:
        return len(self.lon)


class HeadingEnv:
    """N flights stepped at once; `obs` rows follow OBS_COLUMNS, `status` holds RUNNING/SUCCESS/OUT_OF_BOX/STEP_LIMIT."""

    def __init__(self, geometry: HeadingGeometry, altitude: AltitudeNet, weather: pl.DataFrame):
        self.geometry = geometry
        self.altitude = altitude
        g = geometry
        lon_min, lon_max, lat_min, lat_max = g.bbox
        self.weather = WeatherCube(crop_weather(weather, g.bbox), (lon_min, lat_min, lon_max, lat_max), g.weather_time_us)
        self.step_lon = np.cos(g.headings_rad) * g.step_lon_deg  # per action, Eq 6.4
        self.step_lat = np.sin(g.headings_rad) * g.step_lat_deg
        self.n_actions = len(g.headings_rad)

    def reset(self, starts: StartStates) -> np.ndarray:
        """Start len(starts) new trajectories (replacing any running ones); returns their observations."""
        n = len(starts)
        self.lon, self.lat = starts.lon.astype(np.float64).copy(), starts.lat.astype(np.float64).copy()
        self.alt = starts.alt_m.astype(np.float64).copy()
        self.steps = np.zeros(n, dtype=np.int64)
        self.status = np.full(n, RUNNING, dtype=np.int8)
        self.obs = self._observe(np.arange(n))
        return self.obs.copy()

    def restart(self, rows: np.ndarray, starts: StartStates) -> np.ndarray:
        """Restart the trajectories at `rows` (finished episodes) from `starts`; returns all observations."""
        self.lon[rows], self.lat[rows], self.alt[rows] = starts.lon, starts.lat, starts.alt_m
        self.steps[rows] = 0
        self.status[rows] = RUNNING
        self.obs[rows] = self._observe(rows)
        return self.obs.copy()

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Move every running trajectory by its heading (Eq 6.4); finished ones stay where they ended."""
        run = np.flatnonzero(self.status == RUNNING)
        a = np.asarray(actions)[run]
        self.lon[run] += self.step_lon[a]
        self.lat[run] += self.step_lat[a]
        self.alt[run] = self.altitude.predict(self.lon[run], self.lat[run])
        self.steps[run] += 1
        g = self.geometry
        lon_min, lon_max, lat_min, lat_max = g.bbox
        arrived = haversine_km(np.stack([self.lon[run], self.lat[run]], 1), np.array([g.goal_lon, g.goal_lat])) <= g.goal_radius_km
        outside = (self.lon[run] < lon_min) | (self.lon[run] > lon_max) | (self.lat[run] < lat_min) | (self.lat[run] > lat_max)
        status = np.where(arrived, SUCCESS, np.where(outside, OUT_OF_BOX, np.where(self.steps[run] >= g.max_steps, STEP_LIMIT, RUNNING)))
        self.status[run] = status
        self.obs[run] = self._observe(run)
        return self.obs.copy(), self.status.copy()

    def positions(self) -> np.ndarray:
        """(N, 3) lon deg, lat deg, alt m of every trajectory now."""
        return np.stack([self.lon, self.lat, self.alt], axis=1)

    def _observe(self, rows: np.ndarray) -> np.ndarray:
        elapsed_s = self.steps[rows] * self.geometry.dt_s
        pos = np.stack([self.lon[rows], self.lat[rows], self.alt[rows]], axis=1)
        met = self.weather(torch.from_numpy(pos)).numpy()
        return np.concatenate([pos, elapsed_s[:, None], met], axis=1)


@dataclass
class Rollout:
    """Trajectories generated by a policy: positions (T+1, N, 3) lon/lat/alt_m, valid up to `lengths` steps."""

    positions: np.ndarray
    lengths: np.ndarray  # steps taken by each trajectory
    status: np.ndarray  # final status per trajectory

    def trajectory(self, i: int) -> np.ndarray:
        return self.positions[: self.lengths[i] + 1, i]

    @property
    def success(self) -> np.ndarray:
        return self.status == SUCCESS


def rollout(env: HeadingEnv, policy, starts: StartStates) -> Rollout:
    """Run `policy` (observations (N, 7) -> action indices (N,)) from `starts` until every trajectory ends."""
    obs = env.reset(starts)
    positions = [env.positions()]
    while (env.status == RUNNING).any():
        obs, _ = env.step(policy(obs))
        positions.append(env.positions())
    return Rollout(np.stack(positions), env.steps.copy(), env.status.copy())


# ------------------------------------------------------------------ the Table 6.1 protocol (§6.5.1-6.5.2)

# share of a route's flights used for training; P1 trains on the centroid flight only
PARTITIONS = {"P1": None, "P2": 0.1, "P3": 0.5, "P4": 0.9}


class ModelFileError(ValueError):
    """A saved model file is missing, unreadable or not of the expected kind; the message is one line."""


def resample_flights(tracks: pl.DataFrame, n_points: int) -> tuple[list[str], np.ndarray]:
    """Every flight at n_points equidistant in (normalised) time: (flight ids, (F, n_points, 2) lon/lat)."""
    tracks = tracks.sort("flight_id", "ts")
    sizes = tracks.group_by("flight_id", maintain_order=True).len()
    lon_lat = time_normalised(tracks.select("lon", "lat").to_numpy(), sizes["len"].to_numpy().astype(np.int64), n_points)
    return sizes["flight_id"].to_list(), lon_lat


def centroid_flight(tracks: pl.DataFrame) -> str:
    """The flight closest (RMS over 50 time-normalised points) to the mean trajectory: P1's only expert."""
    ids, lon_lat = resample_flights(tracks, 50)
    distance = np.sqrt(((lon_lat - lon_lat.mean(axis=0)) ** 2).sum(-1).mean(-1))
    return ids[int(np.argmin(distance))]


def partition_flights(tracks: pl.DataFrame, partition: str, seed: int) -> tuple[list[str], list[str]]:
    """(train ids, test ids) of one route's flights for a Table 6.1 partition; shuffled by `seed`."""
    if partition not in PARTITIONS:
        raise ValueError(f"partition {partition!r}: expected one of {', '.join(PARTITIONS)}")
    ids = sorted(tracks["flight_id"].unique().to_list())
    if len(ids) < 2:
        raise TrajectoryDataError(f"a partition needs >= 2 flights, got {len(ids)}")
    share = PARTITIONS[partition]
    if share is None:
        train = [centroid_flight(tracks)]
    else:
        n_train = min(max(1, round(share * len(ids))), len(ids) - 1)
        train = sorted(np.random.default_rng(seed).permutation(ids)[:n_train].tolist())
    return train, [f for f in ids if f not in train]


def evaluate_policy(env: HeadingEnv, policy, test_tracks: pl.DataFrame) -> tuple[pl.DataFrame, Rollout]:
    """Roll the policy out from every test flight's first point; per flight: success and DTW-matched errors.

    Errors (models.trajectory.metrics.matched_errors) compare the whole predicted trajectory, successful or
    not, with the real one.
    """
    test_tracks = test_tracks.sort("flight_id", "ts")
    result = rollout(env, policy, StartStates.first_points(test_tracks))
    ids = test_tracks["flight_id"].unique(maintain_order=True).to_list()
    actual = test_tracks.partition_by("flight_id", maintain_order=True)
    rows = [
        {"flight_id": f, "success": bool(result.success[i]), "steps": int(result.lengths[i]),
         **matched_errors(a.select("lon", "lat", "alt_m").to_numpy(), result.trajectory(i))}
        for i, (f, a) in enumerate(zip(ids, actual))
    ]
    return pl.DataFrame(rows), result
