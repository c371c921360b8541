"""One imitation task = one phase (or the whole flight) of one scheme: expert pairs as tensors, goals, start states.

Built from `Demonstrations` and a `TrajectoryEnv`; shared by BC, both GAILs and prediction.
"""

from dataclasses import dataclass

import torch

from models.trajectory.data import Demonstrations, expert_pairs
from models.trajectory.env import TrajectoryEnv, start_day, to_goal_frame
from models.trajectory.nets import Scaler


@dataclass
class Task:
    phase: str
    env: TrajectoryEnv
    n_modes: int
    mode_keys: list[tuple[str, int]]
    goals: torch.Tensor  # (M, 3) lon, lat, alt_m
    max_steps: int  # roll-out limit: 1.5 × the longest demonstration
    obs: torch.Tensor  # (N, OBS_DIM) expert observations
    actions: torch.Tensor  # (N, 3) expert actions in the goal frame (along nm, cross nm, Δalt m)
    modes: torch.Tensor  # (N,) expert global modes
    starts: torch.Tensor  # (N, 3) the position of every expert pair (roll-outs may start anywhere along a demo)
    start_step: torch.Tensor  # (N,) its step index within its demonstration
    start_day: torch.Tensor  # (N,) start_day feature of its demonstration
    pair_goal: torch.Tensor  # (N, 3) the end point of its demonstration (hindsight goal)
    obs_scaler: Scaler
    act_scaler: Scaler

    def candidate_modes(self, route: str) -> list[int]:
        return [g for g, (r, _) in enumerate(self.mode_keys) if r == route]

    def fair_sample(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """Indices of n expert pairs, equally many per mode (§7.5.2: sampling fair across modes)."""
        per_mode = torch.multinomial(torch.ones(self.n_modes), n, replacement=True, generator=gen)
        idx = torch.empty(n, dtype=torch.long)
        for m in range(self.n_modes):  # loop over the few modes, not over samples
            pick = (per_mode == m).nonzero().squeeze(1)
            pool = (self.modes == m).nonzero().squeeze(1)
            idx[pick] = pool[torch.randint(len(pool), (len(pick),), generator=gen)]
        return idx


def build_task(demos: Demonstrations, env: TrajectoryEnv, dt_s: float) -> Task:
    pos, step, act, mode, start_s, end = expert_pairs(demos)
    # Hindsight goals: each expert pair's goal is the end of its own demonstration, so the expert always
    # arrives exactly at its goal and the policy learns to converge on the goal it is given. At prediction
    # the goal is the chosen mode's goal (the mean end point of that mode's training demonstrations).
    pair_goal = torch.as_tensor(end, dtype=torch.float64)
    day = torch.as_tensor(start_day(start_s))
    goals = torch.as_tensor(demos.goals, dtype=torch.float64)
    pos_t = torch.as_tensor(pos, dtype=torch.float64)
    mode_t = torch.as_tensor(mode)
    obs = env.observe(pos_t, torch.as_tensor(step * dt_s, dtype=torch.float64), pair_goal, day)
    act_t = to_goal_frame(obs, torch.as_tensor(act, dtype=torch.float64))
    return Task(
        phase=demos.phase, env=env, n_modes=demos.n_modes, mode_keys=demos.mode_keys, goals=goals,
        max_steps=int(1.5 * max(len(p) for p in demos.points)),
        obs=obs, actions=act_t, modes=mode_t, starts=pos_t, start_step=torch.as_tensor(step), start_day=day, pair_goal=pair_goal,
        obs_scaler=Scaler(obs.mean(0), obs.std(0)), act_scaler=Scaler(act_t.mean(0), act_t.std(0)),
    )
