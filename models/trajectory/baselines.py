"""Baselines a user would pick instead of a learned model (SPEC §2).

constant_velocity: hold the flight's first observed 3D step (Δlon, Δlat, Δalt per Δt) until the goal region,
                   the step limit, the bounding box or the altitude limits end it — in the same environment.
mode_mean:         the mean trajectory of the predicted mode: the mode whose mean trajectory is closest to
                   the flight's first OBSERVED_STEPS points (it sees a few minutes more than the learners).
"""

import numpy as np
import torch

from models.trajectory.data import Demonstrations
from models.trajectory.env import TrajectoryEnv, rollout, start_day
from models.trajectory.metrics import NM_PER_DEG_LAT
from models.units import M_PER_NM

OBSERVED_STEPS = 9  # 3 minutes at 20 s


def resample(points: np.ndarray, n: int) -> np.ndarray:
    """(m, 3) -> (n, 3), linear in the normalised step index."""
    x = np.linspace(0, 1, len(points))
    q = np.linspace(0, 1, n)
    return np.stack([np.interp(q, x, points[:, k]) for k in range(3)], axis=1)


def mode_means(train: Demonstrations) -> dict[int, np.ndarray]:
    """Mean trajectory per global mode, at the mode's median length."""
    out = {}
    for g in range(train.n_modes):
        members = [p for p, m in zip(train.points, train.modes) if m == g]
        n = int(np.median([len(p) for p in members]))
        out[g] = np.mean([resample(p, n) for p in members], axis=0)
    return out


def predict_mode_mean(means: dict[int, np.ndarray], train: Demonstrations, observed: list[np.ndarray],
                      routes: list[str]) -> tuple[list[np.ndarray], np.ndarray]:
    """Per flight: the mean trajectory of the route's mode nearest to its first observed points (mean distance in nm)."""
    preds, modes = [], []
    for obs, route in zip(observed, routes):
        k = min(OBSERVED_STEPS, len(obs))
        cands = train.route_modes(route)
        scale = np.array([NM_PER_DEG_LAT * np.cos(np.radians(obs[0, 1])), NM_PER_DEG_LAT, 1 / M_PER_NM])  # deg, deg, m -> nm
        dist = [np.linalg.norm((means[g][:k] - obs[:k]) * scale, axis=1).mean() for g in cands]
        best = cands[int(np.argmin(dist))]
        preds.append(means[best])
        modes.append(best)
    return preds, np.asarray(modes)


def predict_constant_velocity(env: TrajectoryEnv, observed: list[np.ndarray], goals: np.ndarray, start_s: np.ndarray,
                              max_steps: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Roll the first observed step forward in the environment; returns positions per flight and goal reached."""
    start = torch.as_tensor(np.stack([o[0] for o in observed]))
    step = torch.as_tensor(np.stack([o[1] - o[0] for o in observed]))
    ro = rollout(env, lambda obs: step, start, torch.as_tensor(goals, dtype=torch.float64), max_steps,
                 torch.zeros(len(start), dtype=torch.float64), torch.as_tensor(start_day(start_s)))
    pos, steps = ro.positions.numpy(), ro.steps.numpy()
    return [pos[: steps[k] + 1, k] for k in range(len(observed))], ro.reached.numpy()
