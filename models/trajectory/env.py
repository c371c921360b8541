"""Batched trajectory MDP of §7.3.1, stepping thousands of trajectories at once as torch tensors.

State  s = (lon, lat, alt_m, elapsed_s, temperature_k, wind_u_mps, wind_v_mps,
            goal_east_nm, goal_north_nm, goal_up_m, start_day) — weather at the aircraft's position, where the
            phase's goal lies from here, and the date (days since 2020-01-01 at the start of the roll-out; the
            thesis's state has the time: route modes change with airspace closures, i.e. with the date).
            The thesis's aircraft type and gate delay are not in OpenSky data.
Action a = (Δlon deg, Δlat deg, Δalt m) per Δt. Policies parameterise it in the goal frame — (along nm,
            cross nm, Δalt m) relative to the direction to the goal (`to_goal_frame` / `from_goal_frame`) — so that
            "keep flying as the expert does relative to where it is going" generalises along the route.
Next state (Eq 7.1-7.3): lon' = lon + Δlon, lat' = lat + Δlat, alt' = alt + Δalt, elapsed' = elapsed + Δt,
            weather looked up at the new position.
Termination: within goal_radius_km of the goal (success), step limit, outside the bounding box, or
            altitude outside [alt_min_m, alt_max_m].

Weather: the foundation's `sample_weather` (ISA pressure level, multilinear) is evaluated once on a
regular (alt, lat, lon) cube over the bounding box; each step then reads the cube with a trilinear
`grid_sample` — the same interpolation, batched on tensors, with no per-step rebuild of the grid.
"""

from dataclasses import dataclass

import numpy as np
import polars as pl
import torch
import torch.nn.functional as F

from models.aviation.weather import sample_weather
from models.units import MEAN_EARTH_RADIUS_KM

OBS_NAMES = ("lon", "lat", "alt_m", "elapsed_s", "temperature_k", "wind_u_mps", "wind_v_mps", "goal_east_nm", "goal_north_nm", "goal_up_m",
             "start_day")
OBS_DIM = len(OBS_NAMES)
DAY0_S = 1577836800.0  # 2020-01-01T00:00Z, origin of the start_day feature


def start_day(epoch_s) -> np.ndarray:
    """The start_day feature of flights starting at epoch_s: days since DAY0_S."""
    return (np.asarray(epoch_s, dtype=np.float64) - DAY0_S) / 86400.0


class WeatherCube:
    """Temperature and wind on a regular alt/lat/lon grid, read with trilinear interpolation."""

    def __init__(self, weather: pl.DataFrame, bbox: tuple[float, float, float, float], when_us: int,
                 n_lat: int = 24, n_lon: int = 40, alt_levels_m: np.ndarray | None = None):
        self.lon0, self.lat0, self.lon1, self.lat1 = bbox
        self.alt_m = np.linspace(0.0, 13_000.0, 27) if alt_levels_m is None else np.asarray(alt_levels_m)
        lat = np.linspace(self.lat0, self.lat1, n_lat)
        lon = np.linspace(self.lon0, self.lon1, n_lon)
        aa, la, lo = np.meshgrid(self.alt_m, lat, lon, indexing="ij")
        ts = np.full(aa.size, when_us, dtype="datetime64[us]")
        met = sample_weather(weather, ts, la.ravel(), lo.ravel(), aa.ravel(), alignment="time_of_day")
        cube = np.stack([met["temperature_k"], met["wind_u_mps"], met["wind_v_mps"]]).reshape(3, *aa.shape)
        if not np.isfinite(cube).all():
            raise ValueError("weather: the grid does not cover the flights' bounding box "
                             f"lon {self.lon0:.1f}..{self.lon1:.1f}, lat {self.lat0:.1f}..{self.lat1:.1f}")
        self.cube = torch.as_tensor(cube, dtype=torch.float32)[None]  # (1, 3, alt, lat, lon)

    def __call__(self, pos: torch.Tensor) -> torch.Tensor:
        """(B, 3) lon, lat, alt_m -> (B, 3) temperature_k, wind_u_mps, wind_v_mps (clamped at the cube's edge)."""
        x = 2 * (pos[:, 0] - self.lon0) / (self.lon1 - self.lon0) - 1
        y = 2 * (pos[:, 1] - self.lat0) / (self.lat1 - self.lat0) - 1
        z = 2 * (pos[:, 2] - self.alt_m[0]) / (self.alt_m[-1] - self.alt_m[0]) - 1
        grid = torch.stack([x, y, z], dim=1).to(torch.float32).view(1, 1, 1, -1, 3)
        out = F.grid_sample(self.cube, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out.view(3, -1).T.to(pos.dtype)


def haversine_km(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Great-circle km between (B, ≥2) lon/lat tensors (degrees)."""
    la, lb = torch.deg2rad(a[:, 1]), torch.deg2rad(b[:, 1])
    dlon = torch.deg2rad(b[:, 0] - a[:, 0])
    h = torch.sin((lb - la) / 2) ** 2 + torch.cos(la) * torch.cos(lb) * torch.sin(dlon / 2) ** 2
    return 2 * MEAN_EARTH_RADIUS_KM * torch.asin(torch.sqrt(h.clamp(0, 1)))


def _goal_axes(obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unit vector towards the goal (east, north) and cos(lat) of each observation."""
    g = obs[:, 7:9]
    g = g / g.norm(dim=1, keepdim=True).clamp_min(1e-6)
    return g[:, 0], g[:, 1], torch.cos(torch.deg2rad(obs[:, 1]))


def to_goal_frame(obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """(Δlon, Δlat, Δalt) -> (along-goal nm, cross-goal nm (left +), Δalt m)."""
    gx, gy, coslat = _goal_axes(obs)
    east, north = action[:, 0] * 60.0 * coslat, action[:, 1] * 60.0
    return torch.stack([east * gx + north * gy, -east * gy + north * gx, action[:, 2]], dim=1)


def from_goal_frame(obs: torch.Tensor, frame_action: torch.Tensor) -> torch.Tensor:
    """(along-goal nm, cross-goal nm, Δalt m) -> (Δlon, Δlat, Δalt)."""
    gx, gy, coslat = _goal_axes(obs)
    along, cross = frame_action[:, 0], frame_action[:, 1]
    east, north = along * gx - cross * gy, along * gy + cross * gx
    return torch.stack([east / (60.0 * coslat), north / 60.0, frame_action[:, 2]], dim=1)


@dataclass
class EnvConfig:
    dt_s: float = 20.0
    goal_radius_km: float = 10.0
    alt_min_m: float = -100.0
    alt_max_m: float = 13_500.0
    bbox_margin_deg: float = 1.0


class TrajectoryEnv:
    """B trajectories at once. `reset(start, goal)` then `step(action)` until `done.all()`."""

    def __init__(self, cube: WeatherCube, bbox: tuple[float, float, float, float], cfg: EnvConfig = EnvConfig()):
        self.cube, self.cfg = cube, cfg
        self.lon0, self.lat0, self.lon1, self.lat1 = bbox

    def observe(self, pos: torch.Tensor, elapsed_s: torch.Tensor, goal: torch.Tensor, day: torch.Tensor) -> torch.Tensor:
        """Raw observation (B, OBS_DIM) — shared by roll-outs and by the expert pairs, so both look alike."""
        coslat = torch.cos(torch.deg2rad(pos[:, 1]))
        goal_east = (goal[:, 0] - pos[:, 0]) * 60.0 * coslat
        goal_north = (goal[:, 1] - pos[:, 1]) * 60.0
        return torch.cat([pos, elapsed_s[:, None], self.cube(pos), goal_east[:, None], goal_north[:, None],
                          (goal[:, 2] - pos[:, 2])[:, None], day[:, None].to(pos.dtype)], dim=1)

    def reset(self, start: torch.Tensor, goal: torch.Tensor, max_steps: int, elapsed0_s: torch.Tensor, day: torch.Tensor) -> torch.Tensor:
        """Start B trajectories at (B, 3) positions heading for (B, 3) goals; elapsed0_s = time already flown in
        the phase, day = start_day feature (days since 2020-01-01)."""
        self.pos, self.goal, self.max_steps, self.day = start.clone(), goal, max_steps, day
        self.elapsed0 = elapsed0_s.to(start.dtype)
        self.steps = torch.zeros(len(start), dtype=torch.long)
        self.done = torch.zeros(len(start), dtype=torch.bool)
        self.reached = torch.zeros(len(start), dtype=torch.bool)
        return self.observe(self.pos, self.elapsed0 + self.steps * self.cfg.dt_s, goal, day)

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Apply (Δlon, Δlat, Δalt) to the live trajectories; finished ones stay where they ended."""
        live = ~self.done
        self.pos = torch.where(live[:, None], self.pos + action, self.pos)
        self.steps = self.steps + live.long()
        reached = haversine_km(self.pos, self.goal) <= self.cfg.goal_radius_km
        m = self.cfg.bbox_margin_deg
        outside = ((self.pos[:, 0] < self.lon0 - m) | (self.pos[:, 0] > self.lon1 + m)
                   | (self.pos[:, 1] < self.lat0 - m) | (self.pos[:, 1] > self.lat1 + m))
        bad_alt = (self.pos[:, 2] < self.cfg.alt_min_m) | (self.pos[:, 2] > self.cfg.alt_max_m)
        self.reached |= live & reached
        self.done = self.done | reached | outside | bad_alt | (self.steps >= self.max_steps)
        return self.observe(self.pos, self.elapsed0 + self.steps * self.cfg.dt_s, self.goal, self.day), live


@dataclass
class Rollout:
    obs: torch.Tensor  # (T, B, OBS_DIM) observation before each step
    actions: torch.Tensor  # (T, B, 3)
    live: torch.Tensor  # (T, B) the step was taken (trajectory not yet finished)
    positions: torch.Tensor  # (T + 1, B, 3)
    last_obs: torch.Tensor  # (B, OBS_DIM) observation after the final step
    reached: torch.Tensor  # (B,)
    steps: torch.Tensor  # (B,) steps taken


def rollout(env: TrajectoryEnv, act, start: torch.Tensor, goal: torch.Tensor, max_steps: int,
            elapsed0_s: torch.Tensor, day: torch.Tensor) -> Rollout:
    """Run `act(obs) -> action` on all trajectories until every one is done (one tensor op per step, not per trajectory)."""
    obs = env.reset(start, goal, max_steps, elapsed0_s, day)
    obs_t, act_t, live_t, pos_t = [], [], [], [env.pos]
    while not env.done.all():
        a = act(obs)
        obs_t.append(obs)
        act_t.append(a)
        obs, live = env.step(a)
        live_t.append(live)
        pos_t.append(env.pos)
    return Rollout(torch.stack(obs_t), torch.stack(act_t), torch.stack(live_t), torch.stack(pos_t), obs, env.reached, env.steps)
